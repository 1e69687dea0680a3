"""Configuration files read with bounds (pure): a machine, a scenario or a study file
is input too. A file over ``MAX_FILE_BYTES``, not UTF-8 text (a binary file), invalid
YAML, or a document that expands to more than ``MAX_NODES`` values through its aliases
(a "billion laughs": nine levels of ten aliases load as a few shared lists, then
anything that walks them, ``str()`` or a deep copy, visits 10^9) is refused with a
YamlFileError (a ValueError) naming the file."""

from __future__ import annotations

from pathlib import Path

import yaml

__all__ = ["MAX_FILE_BYTES", "MAX_NODES", "UnreadableFileError", "YamlFileError", "parse_yaml", "read_yaml"]

MAX_FILE_BYTES = 16 * 1024 * 1024
MAX_NODES = 1_000_000            # values of the document with every alias expanded
# libyaml's parser where PyYAML has it (the same documents, ~8x faster: a study's run
# reads its machine files again), else PyYAML's own
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class YamlFileError(ValueError):
    """A configuration file that cannot be taken: names the file (``where``) and why
    (``reason``)."""

    def __init__(self, where: str, reason: str):
        super().__init__(f"{where}: {reason}")
        self.where, self.reason = where, reason

    def __reduce__(self):            # pickled with its fields (a study worker's error reaches its client)
        return type(self), (self.where, self.reason)


class UnreadableFileError(YamlFileError):
    """A file that is no text to read: too large, not UTF-8, binary."""


def expanded_size(data, limit: int = MAX_NODES) -> int:
    """The number of values in ``data`` with every shared (aliased) value counted each
    time it is reached; counting stops past ``limit`` (a self-referential alias never
    ends) and returns limit + 1."""
    count, stack = 0, [data]
    while stack:
        value = stack.pop()
        count += 1
        if count > limit:
            return count
        if isinstance(value, dict):
            stack.extend(value.keys())
            stack.extend(value.values())
        elif isinstance(value, (list, tuple, set)):
            stack.extend(value)
    return count


def parse_yaml(text: str, where: str):
    """``text`` (from ``where``, for the message) as YAML, bounded (module doc)."""
    try:
        data = yaml.load(text, Loader=_LOADER)     # noqa: S506 - a safe loader
    except yaml.YAMLError as exc:
        raise YamlFileError(where, f"invalid YAML: {exc}") from None
    except RecursionError:
        raise YamlFileError(where, "nested too deep") from None
    if expanded_size(data) > MAX_NODES:
        raise YamlFileError(where, f"more than {MAX_NODES} values once its aliases are expanded (an alias bomb?)")
    return data


def read_yaml(path: str | Path):
    """The YAML document of the file ``path``, bounded (module doc); OSError as it comes."""
    return parse_yaml(read_yaml_text(path), str(path))


def read_yaml_text(path: str | Path) -> str:
    """The text of the YAML file ``path``, bounded (module doc), not parsed yet; OSError
    as it comes."""
    path = Path(path)
    with open(path, "rb") as fh:
        raw = fh.read(MAX_FILE_BYTES + 1)
    if len(raw) > MAX_FILE_BYTES:
        raise UnreadableFileError(str(path), f"over {MAX_FILE_BYTES} bytes: not a configuration file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise UnreadableFileError(str(path), f"not UTF-8 text (byte {exc.start}: {raw[exc.start:exc.start + 1]!r}); "
                                             f"a binary file, or another encoding: save it as UTF-8") from None
    if "\x00" in text:
        raise UnreadableFileError(str(path), f"contains a NUL byte (at {text.index(chr(0))}): a binary file")
    return text
