"""How the experiments' reports name and draw each setting, and say who taught: the one place
to extend when a setting (inprocess.SETTINGS) or a teacher profile is added, so that report.md,
sweep.md and the figures show it."""

from __future__ import annotations

from dataclasses import dataclass

from voxshape.services.simteacher.teacher import PROFILES


@dataclass(frozen=True)
class SettingStyle:
    """A setting as the reports show it: its name in tables and legends, its figure marker."""

    label: str
    marker: str  # a matplotlib marker


# Every setting of inprocess.SETTINGS, in the order tables and figures list them.
SETTING_STYLES = {
    "rl": SettingStyle("RL", "s"),
    "rl+f": SettingStyle("RL + F", "D"),
    "rl+f-perfect": SettingStyle("RL + F (PF)", "d"),
    "rl+t": SettingStyle("RL + T", "<"),
    "rl+t+f": SettingStyle("RL + T + F", "^"),
    "rl+t+f-perfect": SettingStyle("RL + T + F (PF)", "v"),
    "rl+f+ask": SettingStyle("RL + F + ask", "o"),
    "rl+t+f+ask": SettingStyle("RL + T + F + ask", "P"),
}


def label(setting: str) -> str:
    """A setting's name in tables and legends: "RL + F" for rl+f."""
    return SETTING_STYLES[setting].label


def teacher_line(summary: dict) -> str:
    """Who taught: the simulated teacher's profile (PROFILES) and the changes made to it."""
    name = summary.get("teacher_profile", "tireless")  # results from before the profiles
    changes = summary.get("teacher_settings") or []
    changed = f", with {', '.join(changes)}" if changes else ""
    return f"The simulated teacher: {name} ({PROFILES[name].describe()}){changed}."
