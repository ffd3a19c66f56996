"""YAML loading that refuses a key given twice in one mapping.

YAML 1.2 requires the keys of a mapping to be unique, but PyYAML keeps the last value of a
repeated key without a word: ``seed: 1`` then ``seed: 2`` further down a file would run seed 2
while the reader of the file sees seed 1. Every config loader of the project reads through
:func:`load_unique`, so such a file is refused with the key and its line.
"""

from __future__ import annotations

import yaml

_BASE = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
"""libyaml's safe loader where PyYAML has it (large world files parse several times faster)."""


def _refuse_repeated_keys(node) -> None:
    """A ``ConstructorError`` when the mapping ``node`` names a key twice."""
    seen: dict = {}
    for key_node, _ in node.value:
        if not isinstance(key_node, yaml.ScalarNode) or key_node.tag.endswith(":merge"):
            continue
        if key_node.value in seen:
            raise yaml.constructor.ConstructorError(
                None,
                None,
                f"key {key_node.value!r} given twice in one mapping "
                f"(first on line {seen[key_node.value] + 1})",
                key_node.start_mark,
            )
        seen[key_node.value] = key_node.start_mark.line


class UniqueKeyLoader(_BASE):
    """The safe loader, refusing a mapping that names a key twice."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            _refuse_repeated_keys(node)
        return super().construct_mapping(node, deep=deep)


def load_unique(text: str):
    """``text`` parsed as YAML by the safe loader; a key given twice in one mapping is a
    ``yaml.YAMLError`` (``ConstructorError``) naming the key and both lines."""
    return yaml.load(text, Loader=UniqueKeyLoader)
