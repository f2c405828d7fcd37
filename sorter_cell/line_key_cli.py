"""
``sorter line-key FILE``: write a new random line key, readable by its owner only.

A line whose segments are started with ``SORTER_LINE_KEY=FILE`` in their environment
seals every message they exchange with it and refuses every message without a good
seal (``sorter_ros.line_key``; docs/simulation-node.md). The key never appears on a
command line or in a log: only the file's path does. The file is created with mode
0600 and never overwritten.
"""

from __future__ import annotations


def add_arguments(parser) -> None:
    """Add the verb's options."""
    parser.add_argument("file", help="the key file to create (refused when it exists)")


def run(args) -> int | str:
    """Write the key; return 0, or the one line saying why it could not."""
    from sorter_ros.line_key import KEY_ENV, LineKeyError, new_key_file

    try:
        new_key_file(args.file)
    except LineKeyError as exc:
        return str(exc)
    print(f"sorter line-key: a new line key in {args.file} (mode 0600); start every segment")
    print(f"of the line, and its warehouse, with {KEY_ENV}={args.file} in the environment")
    return 0
