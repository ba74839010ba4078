"""Words that sound like the vocabulary's: its competitors.

A phrase is heard only when it beats what else the speech could be: above all the words one
sound away from its own ("could", "would", "hood" for "good"). They come from a pronouncing
dictionary (CMUdict, as pocketsphinx ships it): every word whose pronunciation is one phone
substituted, added or dropped from one of the word's, homophones left out (they cannot be
told apart by ear: "write" is "right").

    one_phone_away(("G", "UH", "D"), lexicon)  ->  {"could", "hood", "would", "god", ...}
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from functools import cache
from pathlib import Path

# the 39 phones of CMUdict (no stress marks in pocketsphinx's copy)
PHONES = (
    "AA", "AE", "AH", "AO", "AW", "AY", "B", "CH", "D", "DH", "EH", "ER", "EY", "F", "G",
    "HH", "IH", "IY", "JH", "K", "L", "M", "N", "NG", "OW", "OY", "P", "R", "S", "SH", "T",
    "TH", "UH", "UW", "V", "W", "Y", "Z", "ZH",
)  # fmt: skip
Pronunciation = tuple[str, ...]


def read_dictionary(path: Path) -> dict[str, list[Pronunciation]]:
    """word -> its pronunciations, from a CMU-style dictionary (`word(2)` are variants)."""
    entries: dict[str, list[Pronunciation]] = {}
    with path.open(encoding="utf-8", errors="replace") as f:
        for line in f:
            parts = line.split()
            if len(parts) >= 2:
                entries.setdefault(parts[0].split("(")[0], []).append(tuple(parts[1:]))
    return entries


@cache
def cmudict() -> dict[str, list[Pronunciation]]:
    """pocketsphinx's US-English dictionary, read once."""
    import pocketsphinx

    return read_dictionary(Path(pocketsphinx.get_model_path("en-us/cmudict-en-us.dict")))


def one_edit(pron: Pronunciation) -> set[Pronunciation]:
    """Every sequence one phone substituted, added or dropped from `pron`."""
    out: set[Pronunciation] = set()
    for i in range(len(pron) + 1):
        head, tail = pron[:i], pron[i:]
        out.update((*head, p, *tail) for p in PHONES)  # added
        if tail:
            out.add(head + tail[1:])  # dropped
            out.update((*head, p, *tail[1:]) for p in PHONES if p != tail[0])  # substituted
    return out


class SoundAlikes:
    """Words one phone away from a word, by a dictionary; words of letters only (no
    "good's", no "a.m.")."""

    def __init__(self, lexicon: Mapping[str, list[Pronunciation]]) -> None:
        self.lexicon = lexicon
        self._by_sound: dict[Pronunciation, list[str]] = {}
        for word, prons in lexicon.items():
            if word.isalpha() and word.isascii():
                for pron in prons:
                    self._by_sound.setdefault(pron, []).append(word)

    def of(self, word: str, prons: Iterable[Pronunciation] | None = None) -> list[str]:
        """The words one phone from any pronunciation of `word` (the dictionary's, or
        `prons`), none of them a homophone of it; sorted."""
        prons = list(self.lexicon.get(word, []) if prons is None else prons)
        same = {w for p in prons for w in self._by_sound.get(p, [])}
        near = {w for p in prons for q in one_edit(p) for w in self._by_sound.get(q, [])}
        return sorted(near - same - {word})

    def of_phrase(self, words: tuple[str, ...]) -> list[str]:
        """The phrase with one word replaced by a sound-alike ("go lift" for "go left")."""
        return [
            " ".join((*words[:i], other, *words[i + 1 :]))
            for i, word in enumerate(words)
            for other in self.of(word)
        ]
