"""Simulation presets shipped inside the package (``sim/presets/*.yaml``)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from vdm_aero.errors import SpecError


def preset_names() -> list[str]:
    """Names of the shipped presets, sorted."""
    root = resources.files("sim") / "presets"
    return sorted(p.name.removesuffix(".yaml") for p in root.iterdir() if p.name.endswith(".yaml"))


def preset_text(name: str) -> str:
    """The YAML text of preset ``name``."""
    if name not in preset_names():
        raise SpecError(f"{name}: no such preset and no such file (presets: {', '.join(preset_names())})")
    return (resources.files("sim") / "presets" / f"{name}.yaml").read_text()


def resolve_spec_source(name_or_path: str) -> tuple[str, str]:
    """(origin, YAML text) of a preset name or a spec file path."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        try:
            return str(p), p.read_text()
        except OSError as e:
            raise SpecError(f"{p}: cannot read spec: {e.strerror or e}") from None
    return f"preset:{name_or_path}", preset_text(name_or_path)
