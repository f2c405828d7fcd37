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

from sorter_ros.strict_yaml import StrictYamlError, read_yaml_file


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
