"""
Every YAML the project reads (scenes, study specs, parameters files, --set values) is strict.

A key given twice, an alias (the "billion laughs" expansion), nesting past the
limit, a file larger than the limit or one that never ends (/dev/zero), and text
that is not UTF-8 are each refused with one line naming the file and the rule;
no message echoes a large input whole.
"""

import os
import subprocess
import sys

import pytest

from sorter_ros.strict_yaml import (
    MAX_BYTES,
    MAX_DEPTH,
    StrictYamlError,
    load_yaml_text,
    read_yaml_file,
)

LAUGHS = "\n".join(
    ["a: &a [lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    + [f"{c}: &{c} [{', '.join(['*' + p] * 9)}]" for p, c in zip("abcdefgh", "bcdefghi")]
)


@pytest.mark.parametrize(
    "text, words",
    [
        ("parcel:\n  A: 0.4\n  A: 0.5\n", "key 'A' appears twice"),
        (LAUGHS, "aliases (*a) are not allowed"),
        ("[" * (MAX_DEPTH + 1) + "]" * (MAX_DEPTH + 1), f"nested more than {MAX_DEPTH}"),
        ("[" * 5000, "nested more than"),
        ("a: [1, 2\n", "not valid YAML at line"),
        ("x" * (MAX_BYTES + 1), f"longer than {MAX_BYTES}"),
    ],
)
def test_refused_with_one_line(text, words):
    with pytest.raises(StrictYamlError) as err:
        load_yaml_text(text, "scene file 'x.yaml'")
    msg = str(err.value)
    assert words in msg and msg.startswith("scene file 'x.yaml'") and "\n" not in msg
    assert len(msg) < 400


def test_what_it_accepts_is_plain_yaml():
    assert load_yaml_text("a: {b: [1, 2.5, null, .inf]}\nc: x\n", "t") == {
        "a": {"b": [1, 2.5, None, float("inf")]},
        "c": "x",
    }
    nested = "[" * MAX_DEPTH + "]" * MAX_DEPTH
    assert load_yaml_text(nested, "t") is not None


def test_files_too_large_endless_or_not_text(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_text("#" * (MAX_BYTES + 1))
    with pytest.raises(StrictYamlError, match="more than"):
        read_yaml_file(big, "scene file")
    binary = tmp_path / "bin.yaml"
    binary.write_bytes(b"a: \xff\xfe\n")
    with pytest.raises(StrictYamlError, match="not UTF-8"):
        read_yaml_file(binary, "scene file")
    with pytest.raises(StrictYamlError, match="cannot read"):
        read_yaml_file(tmp_path / "missing.yaml", "scene file")
    if os.path.exists("/dev/zero"):
        with pytest.raises(StrictYamlError, match="more than"):
            read_yaml_file("/dev/zero", "scene file")


@pytest.mark.parametrize(
    "argv, words",
    [
        (["run", "/dev/zero"], "more than"),
        (["run", "{laughs}"], "aliases"),
        (["run", "{dup}"], "appears twice"),
        (["run", "config/scenes/fig9a.yaml", "--set", "parcel.A=" + "[" * 5000], "nested"),
    ],
)
def test_the_command_line_refuses_them_in_one_line(tmp_path, argv, words):
    laughs = tmp_path / "laughs.yaml"
    laughs.write_text(LAUGHS)
    dup = tmp_path / "dup.yaml"
    dup.write_text("belt:\n  v: 1.0\n  v: 1.2\n")
    argv = [a.format(laughs=laughs, dup=dup) for a in argv]
    if argv[1] == "/dev/zero" and not os.path.exists("/dev/zero"):
        pytest.skip("no /dev/zero here")
    r = subprocess.run(
        [sys.executable, "-m", "sorter_sim", *argv],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
    )
    assert r.returncode == 2, r.stderr[-2000:]
    assert words in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr[-2000:]
    assert "Traceback" not in r.stderr
