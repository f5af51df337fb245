"""The library's one YAML reader for user files (camera, sensor, synth, capture and lens configs).

PyYAML's ``safe_load`` resolves YAML 1.1 floats, which need a dot and a signed exponent, so ``exposure_s: 1e-2`` would
be the string ``'1e-2'``. :func:`load_yaml` is ``yaml.SafeLoader`` (plain data, no objects) with the YAML 1.2 float
resolver instead.
"""

from __future__ import annotations

import re

__all__ = ["load_yaml", "check_yaml_mapping"]

# YAML 1.2 floats (core schema): PyYAML's resolver is YAML 1.1's, which needs a dot and a signed exponent, so
# ``1e-2`` and ``1.0e4`` would be strings. This one also reads 1e-2, 1.0e4, -1E+3 and .5e3 as floats (the YAML 1.2
# spec, section 10.2.1.4: ``[-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)([eE][-+]?[0-9]+)?``), and keeps YAML 1.1's ``_``
# separators, sexagesimal values, .inf and .nan.
_YAML12_FLOAT = re.compile(r"""^(?:
     [-+]?[0-9][0-9_]*\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+
    |[-+]?\.[0-9][0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?[0-9][0-9_]*(?::[0-5]?[0-9])+\.[0-9_]*
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""", re.X)


def _config_loader():
    """``yaml.SafeLoader`` with the YAML 1.2 float resolver (built once)."""
    import yaml

    loader = _config_loader.__dict__.get("cls")
    if loader is None:
        tag = "tag:yaml.org,2002:float"

        class ConfigLoader(yaml.SafeLoader):
            """SafeLoader (no object construction) reading YAML 1.2 floats such as ``1e-2`` as floats, and refusing
            a key given twice in one mapping (PyYAML keeps the last: a second ``sensor:`` section replaced the first
            without a word)."""

            def flatten_mapping(self, node):
                # each mapping's own keys, once and before YAML merge keys ('<<') are folded in: a merged node is
                # rewritten in place, its merged and own keys side by side (valid YAML, the own ones win)
                checked = self.__dict__.setdefault("_checked_nodes", set())
                if id(node) not in checked:
                    checked.add(id(node))
                    seen = set()
                    for key_node, _ in node.value:
                        if key_node.tag in ("tag:yaml.org,2002:merge", "tag:yaml.org,2002:value"):
                            continue
                        key = self.construct_object(key_node, deep=True)
                        try:
                            duplicate = key in seen
                            seen.add(key)
                        except TypeError:  # an unhashable key: PyYAML's own error follows
                            continue
                        if duplicate:
                            raise yaml.constructor.ConstructorError(
                                "while constructing a mapping", node.start_mark, f"found the key {key!r} twice",
                                key_node.start_mark)
                super().flatten_mapping(node)

        # a copy of SafeLoader's resolvers with the float one replaced in place (same order of precedence)
        ConfigLoader.yaml_implicit_resolvers = {
            first: [(t, _YAML12_FLOAT if t == tag else rx) for t, rx in resolvers]
            for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}
        for first in "-+0123456789.":
            if not any(t == tag for t, _ in ConfigLoader.yaml_implicit_resolvers.setdefault(first, [])):
                ConfigLoader.yaml_implicit_resolvers[first].append((tag, _YAML12_FLOAT))
        loader = _config_loader.__dict__["cls"] = ConfigLoader
    return loader


def load_yaml(text: str):
    """Parse a config's YAML text safely (``yaml.SafeLoader``: plain data, no objects) with YAML 1.2 floats, so
    ``exposure_s: 1e-2`` is the number 0.01 (``yaml.safe_load``, YAML 1.1, reads it as the string ``'1e-2'``). The
    one YAML reader of user configs (:func:`isettorch.camera.load_config`, :meth:`isettorch.sensor.Sensor.from_config`,
    synth configs, capture.yaml, YAML lenses).

    Example:
        >>> load_yaml("exposure_s: 1e-2\\nfull_well_e: 1.0e4\\nname: '1e-2'")
        {'exposure_s': 0.01, 'full_well_e': 10000.0, 'name': '1e-2'}
    """
    import yaml

    return yaml.load(text, Loader=_config_loader())  # noqa: S506 - a SafeLoader subclass


def check_yaml_mapping(path, name: str, expected: str, *, empty_ok: bool = False) -> None:
    """The YAML file ``path`` given as ``name`` is UTF-8 text whose top level is a mapping (or, with ``empty_ok``,
    empty), else a ValueError naming ``name``, the file and ``expected`` (what the mapping holds). A missing or
    unreadable file and a YAML syntax error pass: the loader's own message names the file."""
    from pathlib import Path

    try:
        text = Path(path).read_bytes().decode("utf-8")
    except OSError:
        return
    except UnicodeDecodeError as err:
        raise ValueError(f"{name}: {path}: not UTF-8 text ({err.reason} at byte {err.start})") from err
    try:
        data = load_yaml(text)
    except Exception:  # noqa: BLE001 - a YAML syntax error: the loader reports it
        return
    if data is None and empty_ok:
        return
    if not isinstance(data, dict):
        raise ValueError(f"{name}: {path}: expected {expected}, got a {type(data).__name__}")
