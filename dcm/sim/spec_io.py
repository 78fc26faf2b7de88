"""Reading the small dataclass specs (bowls, domains) that YAML/JSON configs describe."""

from __future__ import annotations

from dataclasses import fields
from typing import Any, ClassVar


class SpecIO:
    """``from_dict``/``load`` for a spec dataclass: unknown keys and non-mapping files raise ``spec_error``."""

    spec_kind: ClassVar[str]  # "bowl", "domain": names the spec in error messages
    spec_error: ClassVar[type[ValueError]]

    @classmethod
    def from_dict(cls, data: dict[str, Any], where: str | None = None) -> Any:
        """Build from a dict (YAML/JSON); unknown keys raise naming ``where`` and the key."""
        where = where or cls.spec_kind
        known = {f.name for f in fields(cls)}  # type: ignore[arg-type]
        extra = set(data) - known
        if extra:
            raise cls.spec_error(
                f"{where}: unknown {cls.spec_kind} field(s) {sorted(extra)}; known: {sorted(known)}"
            )
        return cls(**data)

    @classmethod
    def load(cls, path: str) -> Any:
        """Read a preset file (YAML or JSON), e.g. ``conf/<kind>/<name>.yaml``."""
        import yaml

        with open(path) as fh:
            data = yaml.safe_load(fh)
        if not isinstance(data, dict):
            raise cls.spec_error(
                f"{path}: expected a mapping of {cls.spec_kind} fields, got {type(data).__name__}"
            )
        return cls.from_dict(data, where=str(path))
