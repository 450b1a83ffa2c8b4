"""Reading the YAML (or JSON) configuration files the commands take: one clear line naming the file
and what is wrong with it (missing, empty, not YAML at a line, not a mapping of options)."""

from __future__ import annotations

import json
import re
from pathlib import Path

from ..errors import InputError


def read_config(path: str | Path, what: str = "config") -> dict:
    """The mapping in the YAML or JSON file ``path`` (``.json`` is read as JSON, anything else as YAML)."""
    import yaml

    path = Path(path)
    if not path.exists():
        raise InputError(f"{what} {path} does not exist")
    if path.is_dir():
        raise InputError(f"{what} {path} is a folder, not a file")
    text = path.read_text(errors="replace")
    if not text.strip():
        raise InputError(f"{what} {path} is an empty file")
    try:
        data = json.loads(text) if path.suffix == ".json" else yaml.load(text, Loader=_unique_keys_loader())
    except json.JSONDecodeError as err:
        raise InputError(f"{what} {path} is not valid JSON (line {err.lineno}: {err.msg})") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        raise InputError(f"{what} {path} is not valid YAML ({where}{getattr(err, 'problem', None) or err})") from None
    if not isinstance(data, dict):
        raise InputError(f"{what} {path} is not a mapping of options (it holds a {type(data).__name__})")
    return data


def _unique_keys_loader():
    """PyYAML's safe loader refusing a key given twice in one mapping (it kept the last without a word: a second
    ``angle_units`` overrode the first), and reading ``1e-3`` as the number it is."""
    import yaml

    class Loader(yaml.SafeLoader):
        pass

    def mapping(loader, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # (<<: merges another mapping: PyYAML's own rules)
                continue
            key = loader.construct_object(key_node, deep=deep)
            try:
                twice = key in seen
            except TypeError:  # an unhashable key (? [x, y]): PyYAML's own error below
                break
            if twice:
                raise yaml.constructor.ConstructorError(None, None, f"the key {key!r} is given twice",
                                                        key_node.start_mark)
            seen.add(key)
        return yaml.SafeLoader.construct_mapping(loader, node, deep)

    Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    # 1e-3 is a number (YAML 1.2; PyYAML's 1.1 reads an exponent without a point as text)
    Loader.add_implicit_resolver("tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9]+(\.[0-9]*)?[eE][-+]?[0-9]+$"),
                                 list("-+0123456789"))
    return Loader


def config_paths(argv: list[str]) -> list[str]:
    """The files given to LightningCLI's ``-c``/``--config`` in ``argv``."""
    out = []
    for i, arg in enumerate(argv):
        if arg in ("-c", "--config") and i + 1 < len(argv):
            out.append(argv[i + 1])
        elif arg.startswith("--config="):
            out.append(arg.split("=", 1)[1])
    return out
