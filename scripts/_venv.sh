# Shared by scripts/run.sh and scripts/test.sh (sourced, not run).
#
# Makes sure the repository's virtualenv .venv exists and holds an editable
# install of sorter_cell with its test extras. The install is refreshed only
# when the packaging files (or the set of top-level packages) changed since the
# last successful install, so repeated runs start at once.
#
# Needs only Python 3.11+ and access to PyPI.

# The caller has already cd'ed to the repository root.

SORTER_PYTHON=${SORTER_PYTHON:-python3}
VENV_DIR=.venv
STAMP_FILE="$VENV_DIR/.sorter_cell_stamp"

export PIP_DISABLE_PIP_VERSION_CHECK=1

# Ctrl-C while the virtualenv is made or refreshed is a stop, not a failed install: the
# stamp is written only after a whole install, so the next run installs again
trap 'echo "stopped (Ctrl-C); the next run finishes the set-up" >&2; exit 130' INT

_sorter_die() {
    echo "error: $*" >&2
    exit 1
}

_sorter_check_python() {
    local py=$1
    command -v "$py" >/dev/null 2>&1 \
        || _sorter_die "'$py' not found; sorter_cell needs Python 3.11 or newer (set SORTER_PYTHON to its path)."
    "$py" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' \
        || _sorter_die "$("$py" --version 2>&1) at '$(command -v "$py")' is too old; sorter_cell needs Python 3.11 or newer (set SORTER_PYTHON to a newer interpreter)."
}

# Hash of everything that decides what `pip install -e .` installs.
_sorter_install_hash() {
    {
        cat setup.py setup.cfg package.xml pyproject.toml 2>/dev/null
        # find_packages() picks up new top-level packages without a setup.py
        # change; the editable finder only knows the ones present at install.
        ls -d -- */__init__.py 2>/dev/null
    } | sha256sum | cut -d' ' -f1
}

_sorter_check_python "$SORTER_PYTHON"

if [ ! -x "$VENV_DIR/bin/python" ]; then
    echo "Creating virtualenv $VENV_DIR ..." >&2
    "$SORTER_PYTHON" -m venv "$VENV_DIR"
    rm -f "$STAMP_FILE"
fi
_sorter_check_python "$VENV_DIR/bin/python"

_sorter_want=$(_sorter_install_hash)
if [ ! -f "$STAMP_FILE" ] || [ "$(cat "$STAMP_FILE")" != "$_sorter_want" ]; then
    echo "Installing sorter_cell and its dependencies into $VENV_DIR ..." >&2
    rm -f "$STAMP_FILE"
    # -qq: errors only; pip's warnings are mostly about local index settings.
    "$VENV_DIR/bin/python" -m pip install -qq --upgrade-strategy only-if-needed -e '.[test]' \
        || _sorter_die "pip install -e '.[test]' into $VENV_DIR failed (see the pip output above)."
    echo "$_sorter_want" > "$STAMP_FILE"
fi
unset _sorter_want
trap - INT
