"""Loads and validates the vocabulary (`vocabulary.toml` beside this file, or a user's own)."""

from __future__ import annotations

import math
import re
import tomllib
import unicodedata
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from voxshape.protocol.messages import ACTION_NAMES, LANGUAGE_PATTERN

DEFAULT_PATH = Path(__file__).with_name("vocabulary.toml")
# The built-in vocabulary's languages. A user's file may add any other ISO 639 code (its phrases
# then travel in utterances of that language; docs/speech.md, adding a language).
LANGUAGES = ("en", "es")
Kind = Literal["qualifier", "goal", "command"]
_KINDS = ("qualifier", "goal", "command")


class VocabularyError(ValueError):
    """The vocabulary file is unusable; the message names the file, the entry and the fix."""


@dataclass(frozen=True)
class Meaning:
    name: str
    kind: Kind
    reward: float | None  # qualifiers and goal
    action: str | None  # commands: one of ACTION_NAMES
    phrases: dict[str, tuple[str, ...]]  # language -> phrases as written in the file


def normalize(text: str) -> str:
    """Case-, accent- and punctuation-insensitive form used for matching."""
    decomposed = unicodedata.normalize("NFKD", text.casefold())
    bare = "".join(c for c in decomposed if not unicodedata.combining(c)).replace("'", "")
    return " ".join(re.sub(r"[^\w]+", " ", bare).split())


# A word that, just before a phrase (within two words), turns it around: "no good".
NEGATIONS = frozenset(
    {"no", "not", "never", "nothing", "without", "dont", "doesnt", "didnt", "isnt", "wasnt"}
    | {"arent", "werent", "cant", "wont"}
)


def spot(
    text: str, phrases: dict[str, str], meanings: dict[str, str] | None = None
) -> tuple[str | None, bool]:
    """The one rule for a phrase inside a sentence, typed or spoken: the longest phrase (as
    written) inside a text of several words, and whether a negation comes just before it:
    (phrase, negated); (None, False) when there is none ("not that way" is a phrase of its
    own), or when, by `meanings` (phrase as written -> its meaning's name), another phrase
    there means something else ("left right"). `phrases`: normalized -> as written."""
    words = normalize(text).split()
    if len(words) < 2:
        return None, False
    found: list[tuple[str, bool]] = []
    taken: set[int] = set()
    for key in sorted(phrases, key=lambda p: -len(p.split())):
        n = len(key.split())
        for i in range(len(words) - n + 1):
            span = set(range(i, i + n))
            if " ".join(words[i : i + n]) == key and not span & taken:
                taken |= span
                found.append((phrases[key], bool(NEGATIONS & set(words[max(0, i - 2) : i]))))
    if not found:
        return None, False
    said = {meanings.get(phrase, phrase) for phrase, _ in found} if meanings else set()
    return (None, False) if len(said) > 1 else found[0]


def written_phrases(vocabulary: Vocabulary, language: str) -> dict[str, str]:
    """Normalized phrase -> the phrase as written, for one language."""
    return {normalize(p): p for p in vocabulary.phrases(language)}


@dataclass(frozen=True)
class Vocabulary:
    meanings: dict[str, Meaning]
    _index: dict[str, Meaning]

    def lookup(self, text: str) -> Meaning | None:
        """The meaning of a whole utterance, or None if it is not in the vocabulary."""
        return self._index.get(normalize(text))

    def find(self, text: str) -> tuple[Meaning | None, str | None, bool]:
        """What an utterance says, typed or spoken alike: the whole of it, else the phrase
        inside it (`spot`, over every language): (meaning, phrase, negated). A negated
        phrase has no meaning ("no good": nothing)."""
        whole = self.lookup(text)
        if whole is not None:
            return whole, text, False
        written = {key: key for key in self._index}
        names = {key: meaning.name for key, meaning in self._index.items()}
        phrase, negated = spot(text, written, names)
        meaning = None if phrase is None or negated else self._index[phrase]
        return meaning, phrase, negated

    @property
    def languages(self) -> tuple[str, ...]:
        """The languages with at least one phrase, in the order the file first uses them."""
        seen = (lang for m in self.meanings.values() for lang, p in m.phrases.items() if p)
        return tuple(dict.fromkeys(seen))

    def phrases(self, language: str) -> list[str]:
        """Every phrase of one language, as written (for recognizer grammars)."""
        if language not in self.languages:
            known = ", ".join(self.languages)
            raise VocabularyError(f"unknown language {language!r}; this vocabulary has {known}")
        return [p for m in self.meanings.values() for p in m.phrases.get(language, ())]

    def words(self, language: str) -> list[str]:
        """The distinct words of one language's phrases, normalized (for word lists)."""
        return sorted({w for p in self.phrases(language) for w in normalize(p).split()})


def load_vocabulary(path: str | Path | None = None) -> Vocabulary:
    """Reads and validates a vocabulary file; raises VocabularyError naming what is wrong."""
    path = Path(path) if path is not None else DEFAULT_PATH
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise VocabularyError(f"{path}: no such vocabulary file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise VocabularyError(f"{path}: not valid TOML: {e}") from None
    return parse_vocabulary(data, source=str(path))


def parse_vocabulary(data: dict, source: str = "<vocabulary>") -> Vocabulary:
    if data.pop("version", None) != 1:
        raise VocabularyError(f"{source}: needs `version = 1` at the top")
    meanings: dict[str, Meaning] = {}
    index: dict[str, Meaning] = {}
    for name, entry in data.items():
        where = f"{source} [{name}]"
        if not isinstance(entry, dict):
            raise VocabularyError(f"{where}: expected a table of kind, reward/action and phrases")
        meaning = _parse_meaning(name, entry, where)
        for language, phrases in meaning.phrases.items():
            for phrase in phrases:
                key = normalize(phrase)
                if not key:
                    raise VocabularyError(f"{where}: {language} phrase {phrase!r} has no words")
                other = index.setdefault(key, meaning)
                if other is not meaning:
                    raise VocabularyError(
                        f"{where}: {phrase!r} already means [{other.name}]; a phrase may have"
                        " one meaning only (remove it from one of them)"
                    )
        meanings[name] = meaning
    if not meanings:
        raise VocabularyError(f"{source}: defines no meanings")
    return Vocabulary(meanings, index)


def _parse_meaning(name: str, entry: dict, where: str) -> Meaning:
    # every key but these names a language: the built-in ones, or another ISO 639 code
    fields = {"kind", "reward", "action"}
    unknown = sorted(k for k in entry if k not in fields and not re.fullmatch(LANGUAGE_PATTERN, k))
    if unknown:
        raise VocabularyError(
            f"{where}: unknown key {unknown[0]!r}; allowed: {sorted(fields)} and languages, "
            f"as ISO 639 codes of 2-3 lowercase letters ({', '.join(LANGUAGES)}, ko, ...)"
        )
    kind = entry.get("kind")
    if kind not in _KINDS:
        raise VocabularyError(f"{where}: unknown meaning kind {kind!r}; use one of {_KINDS}")
    reward = entry.get("reward")
    action = entry.get("action")
    if kind == "command":
        if action not in ACTION_NAMES:
            raise VocabularyError(f"{where}: action {action!r} is not one of {ACTION_NAMES}")
        if reward is not None:
            raise VocabularyError(f"{where}: a command has an action, not a reward")
    else:
        if isinstance(reward, bool) or not isinstance(reward, int | float):
            raise VocabularyError(f"{where}: a {kind} needs a numeric `reward`")
        if not math.isfinite(reward):
            raise VocabularyError(f"{where}: reward {reward!r} is not finite")
        if action is not None:
            raise VocabularyError(f"{where}: a {kind} has a reward, not an action")
    phrases = {}
    for language in dict.fromkeys([*LANGUAGES, *(k for k in entry if k not in fields)]):
        listed = entry.get(language, [])
        if not isinstance(listed, list) or not all(isinstance(p, str) for p in listed):
            raise VocabularyError(f"{where}: `{language}` must be a list of strings")
        phrases[language] = tuple(listed)
    if not any(phrases.values()):
        raise VocabularyError(f"{where}: no phrases in any language")
    return Meaning(name, kind, None if reward is None else float(reward), action, phrases)
