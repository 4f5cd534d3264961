#!/bin/sh
# One-command setup for a fresh Debian / Raspberry Pi OS machine.
#   ./bootstrap.sh demo    install into .venv, then run `preflight demo`
#   ./bootstrap.sh test    install into .venv with test extras, then run the test suite
# Extra arguments after the mode are passed to preflight demo / pytest.
set -eu
cd "$(dirname "$0")"
mode="${1:-demo}"
[ $# -gt 0 ] && shift

need_apt=""
command -v python3 >/dev/null 2>&1 || need_apt="python3"
if ! python3 -c 'import venv, ensurepip' >/dev/null 2>&1; then need_apt="$need_apt python3-venv"; fi
if [ -n "$need_apt" ]; then
    echo "bootstrap: installing $need_apt with apt-get" >&2
    if [ "$(id -u)" -eq 0 ]; then SUDO=""; else SUDO="sudo"; fi
    $SUDO apt-get update -qq && $SUDO apt-get install -y -qq $need_apt python3-pip
fi

if [ ! -x .venv/bin/python ]; then
    python3 -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip >/dev/null 2>&1 || true

case "$mode" in
    demo)
        .venv/bin/python -m pip install -q .
        exec .venv/bin/preflight demo "$@"
        ;;
    test)
        .venv/bin/python -m pip install -q -e '.[test]'
        .venv/bin/ruff check --quiet . || { echo "bootstrap: ruff found problems (above)" >&2; exit 1; }
        exec .venv/bin/python -m pytest "$@"
        ;;
    *)
        echo "usage: ./bootstrap.sh demo|test [args...]" >&2
        exit 2
        ;;
esac
