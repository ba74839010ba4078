"""Spanish words in the US-English model's phones: pocketsphinx hears Spanish without a
Spanish model. Spanish spelling is nearly phonemic, so a handful of rules (Latin American:
c/z before e/i are s, ll is y) give each word's phones in the English phone set; the
closest English phone stands for each Spanish one (its five pure vowels by AA EH IY OW UW).

    pronunciations("izquierda")  ->  [("IY", "S", "K", "Y", "EH", "R", "D", "AA"), ...]
"""

from __future__ import annotations

import unicodedata

VOWELS = {"a": "AA", "e": "EH", "i": "IY", "o": "OW", "u": "UW"}
# Other renderings of a vowel an English-trained model may hear in Spanish speech.
VOWEL_VARIANTS = {"EH": ("EY",), "OW": ("AO",), "AA": ("AH", "AE")}
CONSONANTS = {
    "b": "B", "v": "B", "d": "D", "f": "F", "k": "K", "l": "L", "m": "M", "n": "N",
    "p": "P", "s": "S", "t": "T", "w": "W", "z": "S", "j": "HH", "r": "R",
}  # fmt: skip


def _letters(word: str) -> str:
    """Lower case without accents, keeping ñ and ü's diaeresis as marks the rules read."""
    decomposed = unicodedata.normalize("NFD", word.casefold().replace("ñ", "\0"))
    kept = "".join(c for c in decomposed if c == "\u0308" or not unicodedata.combining(c))
    return kept.replace("\0", "ñ").replace("u\u0308", "ü")


def phones(word: str) -> tuple[str, ...]:
    """The phones of one Spanish word, by rule."""
    w = _letters(word)
    out: list[str] = []
    i = 0
    while i < len(w):
        c, nxt = w[i], w[i + 1 : i + 2]
        after = w[i + 2 : i + 3]
        if c in "aeiou":
            glide = c in "iu" and nxt in VOWELS and not (out and out[-1] in ("Y", "W"))
            if c == "i" and glide:
                out.append("Y")
            elif c == "u" and glide:
                out.append("W")
            else:
                out.append(VOWELS[c])
        elif c == "ü":
            out.append("W")
        elif c == "c" and nxt == "h":
            out.append("CH")
            i += 1
        elif c == "c":
            out.append("S" if nxt in ("e", "i") else "K")
        elif c == "q":
            out.append("K")
            i += 1 if nxt == "u" else 0
        elif c == "g" and nxt == "u" and after in ("e", "i"):
            out.append("G")
            i += 1
        elif c == "g":
            out.append("HH" if nxt in ("e", "i") else "G")
        elif c == "l" and nxt == "l":
            out.append("Y")
            i += 1
        elif c == "r" and nxt == "r":
            out.append("R")
            i += 1
        elif c == "ñ":
            out += ["N", "Y"]
        elif c == "x":
            out += ["K", "S"]
        elif c == "y":
            out.append("IY" if not nxt or nxt not in VOWELS else "Y")
        elif c == "h":
            pass  # silent
        elif c in CONSONANTS:
            out.append(CONSONANTS[c])
        i += 1
    return tuple(p for k, p in enumerate(out) if k == 0 or p != out[k - 1])  # "xc": one S


def pronunciations(word: str) -> list[tuple[str, ...]]:
    """The rule's phones first, then variants with the English vowels an English-trained
    model may match Spanish a, e and o to (one vowel at a time, all its places)."""
    main = phones(word)
    variants = [main]
    for plain, others in VOWEL_VARIANTS.items():
        for other in others if plain in main else ():
            variants.append(tuple(other if p == plain else p for p in main))
    return list(dict.fromkeys(variants))


def spoken_forms(phrase: str) -> list[tuple[str, ...]]:
    """The phrase's words as written, and as said when a vowel word merges into the vowel
    before it ("gira a la izquierda" is said "gira la izquierda")."""
    words = tuple(phrase.split())
    merged = tuple(
        w
        for k, w in enumerate(words)
        if not (k > 0 and w in VOWELS and _letters(words[k - 1]).endswith(w))
    )
    return list(dict.fromkeys([words, merged]))
