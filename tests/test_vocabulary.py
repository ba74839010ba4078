"""The vocabulary file: the paper's words and rewards, and clear errors for bad files."""

from __future__ import annotations

import pytest

from tests.test_arbiter import arbiter, feedback, notices, shown
from voxshape.protocol import ACTION_NAMES, VocabularyError, load_vocabulary
from voxshape.protocol.vocabulary import normalize
from voxshape.services.arbiter.scripted import utterance

PAPER_TABLE_1 = {  # Spanish word -> meaning (the paper's Table 1 and Section 4)
    "avanzar": "forward",
    "regresar": "back",
    "izquierda": "left",
    "derecha": "right",
    "fin": "stop",
    "final": "stop",
    "bien": "good",
    "mal": "bad",
    "excelente": "excellent",
    "terrible": "terrible",
    "objetivo": "goal",
    "hacia adelante": "forward",
    "hacia atrás": "back",
    "gira a la izquierda": "left",
    "ve a tu derecha": "right",
    "para ahí": "stop",
    "sigue así": "good",
    "por ahí no": "bad",
    "muy bien": "excellent",
    "así no": "terrible",
    "hasta ahí": "goal",
}


@pytest.fixture(scope="module")
def vocab():
    return load_vocabulary()


@pytest.mark.parametrize(("phrase", "meaning"), PAPER_TABLE_1.items())
def test_paper_table_1_is_in_the_vocabulary(vocab, phrase, meaning):
    assert vocab.lookup(phrase).name == meaning


def test_paper_rewards(vocab):
    rewards = {n: m.reward for n, m in vocab.meanings.items() if m.reward is not None}
    assert rewards == {"goal": 100, "excellent": 50, "good": 10, "bad": -10, "terrible": -50}


def test_every_command_and_english(vocab):
    commands = {m.action for m in vocab.meanings.values() if m.kind == "command"}
    assert commands == set(ACTION_NAMES)
    for word in [
        "good",
        "bad",
        "excellent",
        "terrible",
        "goal",
        "forward",
        "back",
        "left",
        "right",
        "stop",
    ]:
        assert vocab.lookup(word) is not None, word


def test_matching_ignores_case_accents_punctuation(vocab):
    assert vocab.lookup("  HACIA ATRAS! ").name == "back"
    assert vocab.lookup("That's it.").name == "good"
    assert vocab.lookup("go to the kitchen") is None
    assert normalize("¡Así   no!") == "asi no"


def test_phrases_and_words_per_language(vocab):
    assert "gira a la izquierda" in vocab.phrases("es")
    assert "izquierda" in vocab.words("es") and "left" not in vocab.words("es")
    with pytest.raises(VocabularyError, match="unknown language 'fr'"):
        vocab.phrases("fr")


def test_a_vocabulary_may_add_a_language(tmp_path):
    from voxshape.protocol.vocabulary import LANGUAGES

    assert load_vocabulary().languages == LANGUAGES  # the built-in file's, in its order
    path = write(tmp_path, 'version = 1\n[good]\nkind="qualifier"\nreward=10\nko=["좋아"]\n')
    korean = load_vocabulary(path)
    assert korean.languages == ("ko",) and korean.phrases("ko") == ["좋아"]
    assert korean.lookup("좋아").name == "good"
    with pytest.raises(VocabularyError, match="unknown language 'en'; this vocabulary has ko"):
        korean.phrases("en")


def write(tmp_path, text):
    path = tmp_path / "vocab.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize(
    ("text", "error"),
    [
        (
            'version = 1\n[good]\nkind="qualifier"\nreward=10\nen=["good"]\n'
            '[fine]\nkind="qualifier"\nreward=5\nen=["Good!"]\n',
            r"\[fine\]: 'Good!' already means \[good\]",
        ),
        ('version = 1\n[x]\nkind="praise"\nreward=1\nen=["x"]\n', "unknown meaning kind 'praise'"),
        (
            'version = 1\n[x]\nkind="command"\naction="jump"\nen=["jump"]\n',
            "action 'jump' is not one of",
        ),
        ('version = 1\n[x]\nkind="qualifier"\nen=["x"]\n', "needs a numeric `reward`"),
        ('version = 1\n[x]\nkind="qualifier"\nreward=true\nen=["x"]\n', "needs a numeric `reward`"),
        ('version = 1\n[x]\nkind="qualifier"\nreward=nan\nen=["x"]\n', "not finite"),
        ('version = 1\n[x]\nkind="command"\naction="left"\nreward=3\nen=["x"]\n', "not a reward"),
        ('version = 1\n[x]\nkind="qualifier"\nreward=1\nFrench=["x"]\n', "unknown key 'French'"),
        ('version = 1\n[x]\nkind="qualifier"\nreward=1\nko="x"\n', "`ko` must be a list"),
        ('version = 1\n[x]\nkind="qualifier"\nreward=1\n', "no phrases"),
        ('version = 1\n[x]\nkind="qualifier"\nreward=1\nen=["?!"]\n', "has no words"),
        ('version = 1\n[x]\nkind="qualifier"\nreward=1\nen="x"\n', "must be a list of strings"),
        ('[x]\nkind="qualifier"\nreward=1\nen=["x"]\n', "needs `version = 1`"),
        ("version = 1\n", "defines no meanings"),
        ("version = 1\n[x\n", "not valid TOML"),
    ],
)
def test_bad_vocabulary_files_get_clear_errors(tmp_path, text, error):
    path = write(tmp_path, text)
    with pytest.raises(VocabularyError, match=error) as info:
        load_vocabulary(path)
    assert str(path) in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(VocabularyError, match="no such vocabulary file"):
        load_vocabulary(tmp_path / "nope.toml")


@pytest.mark.parametrize(
    ("text", "kind", "expected"),
    [
        ("could you go left", "command", "left"),  # the README's, typed
        ("please turn to your left now", "command", "left"),
        ("that's good", "reward", 10.0),
        ("bien bien", "reward", 10.0),
        ("no good", None, "'good' is negated in 'no good'"),
        ("left, no, right", None, "is not in the vocabulary"),  # two meanings: neither
    ],
)
def test_a_phrase_in_a_sentence_is_credited_by_the_speech_engines_rule(text, kind, expected):
    """Typed words meet the rule the speech engines spot a phrase in a sentence by
    (voxshape/protocol/vocabulary.py's spot): typed, "could you go left" was "not in the
    vocabulary"; the hint names commands as well as qualifiers."""
    a = arbiter()
    out = a.on_utterance(utterance("ana", "r1", text, shown(90)), shown(99))
    if kind is None:
        (notice,) = notices(out)
        assert expected in notice.text and not feedback(out)
        assert "good" in notice.text and "left" in notice.text  # a qualifier and a command
        return
    (fb,) = feedback(out)
    assert fb.kind == kind and (fb.reward if kind == "reward" else fb.command) == expected
