"""
Reading a ROS 2 parameters file (``--params-file``) without ROS, strictly.

The nodes get their files through rcl; the tools that plan around a node (the demo
reads the controller's file to plan its stream) read the same file here, with the
same rules the node applies and a few YAML ones rcl does not: a size limit, no
duplicate keys, no aliases, bounded nesting (``strict_yaml``), a mapping where one
is due. Errors are ``ValueError`` naming the file and the key.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sorter_ros.strict_yaml import MAX_BYTES, StrictYamlError, read_yaml_file

MAX_VALUE_CHARS = 4096  # a string parameter's characters: a path, a frame, names
MAX_LIST_ITEMS = 4096  # items of a list parameter
MAX_FILE_PARAMETERS = 2000  # parameters one file sets, all nodes together (ours: ~150)


def _flat(prefix: str, mapping: dict):
    for key, value in mapping.items():
        if isinstance(value, dict):
            yield from _flat(f'{prefix}{key}.', value)
        else:
            yield f'{prefix}{key}', value


def read_params_file(path: Path, node_name: str) -> dict[str, Any]:
    """
    Return ``node_name``'s parameters in ``path`` as {dotted name: value}.

    The node's section may be written ``node_name``, ``/node_name`` or
    ``/**/node_name`` (any namespace), as rcl accepts them.

    Parameters
    ----------
    path : str or Path
        The ROS 2 parameters file.
    node_name : str
        The node.

    Returns
    -------
    dict
        {dotted name: value}.

    Raises
    ------
    StrictYamlError
        The file unreadable, not a parameters file, or without the node's section.

    """
    path = Path(path)
    try:
        doc = read_yaml_file(path, 'parameters file')
    except StrictYamlError as exc:
        raise ValueError(str(exc)) from None
    if not isinstance(doc, dict):
        raise ValueError(f'{path}: a parameters file is a mapping of node names')
    for section in (f'/**/{node_name}', f'/{node_name}', node_name):
        if section in doc:
            params = doc[section]
            if not isinstance(params, dict) or not isinstance(params.get('ros__parameters'), dict):
                raise ValueError(
                    f'{path}: section {section!r} must hold a ros__parameters mapping'
                )
            return dict(_flat('', params['ros__parameters']))
    raise ValueError(f'{path}: no section for node {node_name!r} (expected /**/{node_name})')


def _leaves(prefix: str, value, depth: int = 0):
    if isinstance(value, dict):
        for key, inner in value.items():
            yield from _leaves(f'{prefix}.{key}' if prefix else str(key), inner, depth + 1)
    else:
        yield prefix, value


def _value_problem(name: str, value) -> str | None:
    items = value if isinstance(value, list) else [value]
    if isinstance(value, list) and len(value) > MAX_LIST_ITEMS:
        return f'{name!r} is a list of {len(value)} items, more than the {MAX_LIST_ITEMS} allowed'
    for item in items:
        if isinstance(item, str) and len(item) > MAX_VALUE_CHARS:
            return (
                f'{name!r} is {len(item)} characters, more than the {MAX_VALUE_CHARS} a '
                'value may have'
            )
    return None


def params_file_problem(path: str | Path) -> str | None:
    """
    Say why rcl must not be given the params file ``path`` (None when it may).

    rcl reads a params file whole and without bounds: a value of 50 MB (700 MB of
    memory by the time the node is ready), a key given twice (the last one wins, without
    a word), 100 000 parameters (a minute of silence before the node says anything) or
    nesting thousands deep (an error of 40 kB). Here the file is read as the project
    reads every YAML file (``strict_yaml``: at most a megabyte, no duplicate key, no
    alias, 32 levels), then every value is bounded: ``MAX_VALUE_CHARS`` characters a
    string, ``MAX_LIST_ITEMS`` items a list, ``MAX_FILE_PARAMETERS`` parameters the file.

    Parameters
    ----------
    path : str or Path
        The file, as given after ``--params-file``.

    Returns
    -------
    str or None
        One line naming the file, the parameter, the size and the limit.

    """
    label = f'params file {str(path)[:200]!r}'
    p = Path(path)
    try:
        size = p.stat().st_size
    except OSError:
        return None  # rcl says it cannot open it, with where the shipped ones are
    if size > MAX_BYTES:
        return f'{label} is {size} bytes, more than the {MAX_BYTES} a params file may have'
    try:
        doc = read_yaml_file(p, 'params file')
    except StrictYamlError as exc:
        return str(exc)[:400]
    if not isinstance(doc, dict):
        return f'{label}: a parameters file is a mapping of node names'
    n = 0
    for section, body in doc.items():
        params = body.get('ros__parameters') if isinstance(body, dict) else None
        for name, value in _leaves('', params if isinstance(params, dict) else {}):
            n += 1
            if n > MAX_FILE_PARAMETERS:
                return (
                    f'{label} sets more than the {MAX_FILE_PARAMETERS} parameters a params '
                    'file may set'
                )
            problem = _value_problem(name, value)
            if problem:
                return f'{label}, section {str(section)[:80]!r}: {problem}'
    return None


def ros_arguments_problem(args) -> str | None:
    """
    Check a command line's parameters before rcl reads them: each params file, each ``-p``.

    A ``-p NAME:=VALUE`` is bounded as a params file's value is (``MAX_VALUE_CHARS``:
    the system lets one argument be 128 kB); a ``--params-file`` is checked whole
    (``params_file_problem``).

    Parameters
    ----------
    args : list of str
        The command line.

    Returns
    -------
    str or None
        The first problem, in one line naming the size and the limit.

    """
    args = list(args or [])
    for _, flag, value in ros_arguments(args):
        if flag == '--params-file':
            problem = params_file_problem(value)
            if problem:
                return problem
        elif flag in ('-p', '--param') and len(value) > MAX_VALUE_CHARS + 200:
            name = value.split(':=', 1)[0][:80]
            return (
                f'-p {name}:=...: the rule is {len(value)} characters, more than the '
                f'{MAX_VALUE_CHARS} a value may have'
            )
    return None


def ros_arguments(args: list):
    """
    Yield (index of the value, flag, value) of each flagged ROS argument of a command line.

    Only what lies in a ``--ros-args`` section is ROS's (up to a ``--``): ``-p``,
    ``--param``, ``-r``, ``--remap``, ``--params-file`` and the like, each with the
    argument after it.
    """
    in_ros = False
    for k, arg in enumerate(args[:-1]):
        if arg == '--ros-args':
            in_ros = True
        elif arg == '--':
            in_ros = False
        elif in_ros and arg.startswith('-'):
            yield k + 1, arg, args[k + 1]
