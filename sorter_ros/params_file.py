"""
Reading a ROS 2 parameters file (``--params-file``) without ROS, strictly.

The nodes get their files through rcl; the tools that plan around a node (the demo
reads the controller's file to plan its stream) read the same file here, with the
same rules the node applies and a few YAML ones rcl does not: a size limit, no
duplicate keys, a mapping where one is due. Errors are ``ValueError`` naming the
file and the key.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

MAX_BYTES = 1 << 20  # a parameters file is a few kB; refuse anything near a megabyte


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that refuses a key given twice in one mapping (YAML keeps the last)."""


def _mapping(loader: _StrictLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f'key {key!r} appears twice', key_node.start_mark
            )
        seen.add(key)
    return yaml.SafeLoader.construct_mapping(loader, node, deep)


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping)


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
    """
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_BYTES:
            raise ValueError(
                f'{path}: {size} bytes, more than a parameters file may have ({MAX_BYTES} bytes)'
            )
        doc = yaml.load(path.read_text(), Loader=_StrictLoader)  # noqa: S506 (strict SafeLoader)
    except OSError as exc:
        raise ValueError(f'{path}: cannot read it ({exc.strerror})') from None
    except yaml.YAMLError as exc:
        raise ValueError(
            f'{path}: not valid YAML for a parameters file: {str(exc).splitlines()[0][:200]}'
        ) from None
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
