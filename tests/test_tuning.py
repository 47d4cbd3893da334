"""The tuned numbers of the reconstruction: one home per number (reconstruct/tuning.py), its docs table in step.

* docs/design/reconstruction.md's constants block is exactly :func:`constants_table`;
* every field says what it does, its units and where its value comes from (one of the kinds);
* every module-level UPPER_CASE numeric name defined in ``reconstruct/*.py`` is an alias of
  a field (the same object) or sits in :data:`NOT_TUNED` with its reason;
* the settings are frozen: a changed value is a new instance.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import re
from pathlib import Path

import pytest

from reflecto import polar
from reflecto.reconstruct import tuning

ROOT = Path(__file__).resolve().parents[1]
RECONSTRUCT = ROOT / "src" / "reflecto" / "reconstruct"
DOC = ROOT / "docs" / "design" / "reconstruction.md"

#: Module-level numeric constants of reconstruct/ that are not tuned numbers, and why.
NOT_TUNED = {
    ("samples", "KD_BOUND_Z"): "derived: Φ⁻¹(1 − q/100) of KD_BOUND_PERCENTILE q for Gaussian noise, not a choice",
    ("samples", "_SUBSAMPLE"): "speed only: the stride of a pre-selection threshold; the percentile is exact "
                               "whatever the stride (kd_upper_bound gathers a whole channel when it keeps too few)",
    ("normal", "MIN_VIEW_COS"): "derived: sin of MIN_VIEW_DEG, the tuned field",
    ("_polar_kernels", "TD_EDGE_MARGIN"): "exactness, not a choice: any margin well above arccos's rounding "
                                          "(≈ 1e-16) and below the cells' width gives the arccos's cells",
    ("symmetry", "MIN_ELEVATION_DEG"): "the device's definition of a steep LED "
                                       "(instrument.device.STEEP_ELEVATION_DEG), not a reconstruction choice",
    ("pipeline", "MAX_RESOLUTION"): "an input limit of Options (memory: 2048² cells per face), not a fit's choice",
    ("pipeline", "SIGNAL_SIGMAS"): "a detection threshold of the camera's noise model (5 σ: a Gaussian passes it on "
                                   "3e-7 of the samples), not a fit's choice",
    ("pipeline", "MAX_TILT_MARGIN_DEG"): "wording only: when a note says the tilt sits at the search's bound "
                                         "(the estimate holds it there to its last digits); no fit reads it",
}

#: Modules another change is rewriting: their constants are still literals, checked for
#: the field's value and type until they become aliases (then drop them from here).
PENDING_ALIAS: set[str] = set()


def _fields():
    for instance_name, stage in tuning.STAGES.items():
        for f in dataclasses.fields(stage):
            yield instance_name, stage, f


def _numeric(v) -> bool:
    if isinstance(v, bool):
        return False
    if isinstance(v, (int, float)):
        return True
    if isinstance(v, tuple):
        return bool(v) and all(_numeric(x) for x in v)
    if isinstance(v, dict):
        return bool(v) and all(_numeric(x) for x in v.values())
    return False


def _defined_constants(path: Path) -> list[str]:
    """UPPER_CASE names assigned at module level (not imported) in a module's source."""
    names = []
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, ast.AnnAssign):
            targets = [node.target]
        else:
            continue
        names += [t.id for t in targets if isinstance(t, ast.Name) and re.fullmatch(r"_?[A-Z][A-Z0-9_]*", t.id)]
    return names


def _aliases() -> dict[tuple[str, str], tuple[object, str, str | None]]:
    """``(module, NAME) → (stage, field, dict key or None)`` from the fields' metadata."""
    out: dict[tuple[str, str], tuple[object, str, str | None]] = {}
    for _, stage, f in _fields():
        module = type(stage).module.rsplit(".", 1)[-1]
        for ref in [f"{module}.{f.metadata['name']}", *f.metadata["also"]]:
            mod, name = ref.split(".", 1)
            m = re.fullmatch(r'(\w+)\["(\w+)"\]', name)
            key = (mod, m.group(1)) if m else (mod, name)
            assert key not in out or m, f"{ref} is claimed by two fields"
            out[(mod, f"{key[1]}[{m.group(2)}]") if m else key] = (stage, f.name, m.group(2) if m else None)
    return out


def test_the_docs_constants_block_is_the_generated_table():
    block = tuning.document_block(DOC.read_text(encoding="utf-8"))
    assert block == f"{tuning.BEGIN_MARKER}\n\n{tuning.constants_table()}\n{tuning.END_MARKER}", (
        "docs/design/reconstruction.md's constants table differs from reconstruct/tuning.py: run "
        "`python -m reflecto.reconstruct.tuning --update docs/design/reconstruction.md`")


def test_the_table_lists_every_field_once():
    rows = [line for line in tuning.constants_table().splitlines() if line.startswith("| `")]
    assert len(rows) == sum(1 for _ in _fields())
    assert "`isotropic.ETA_MAX`<br>`fresnel_fit.ETA_MAX` | 50 |" in tuning.constants_table()


@pytest.mark.parametrize("instance_name, stage, field", list(_fields()),
                         ids=[f"{n}.{f.name}" for n, _, f in _fields()])
def test_every_field_states_what_units_and_a_source_of_a_known_kind(instance_name, stage, field):
    m = field.metadata
    assert m["what"].strip() and m["units"].strip() and m["name"].strip()
    kind, _, text = m["source"].partition(":")
    assert kind in tuning.KINDS and text.strip(), f"{instance_name}.{field.name}: source {m['source']!r}"
    assert _numeric(getattr(stage, field.name))


def test_each_stage_names_its_module_and_the_paper():
    for stage in tuning.STAGES.values():
        importlib.import_module(type(stage).module)
        assert type(stage).paper and type(stage).__doc__


def test_every_module_level_numeric_constant_of_reconstruct_is_a_field_alias_or_listed_as_not_tuned():
    aliases = _aliases()
    stray, wrong, seen = [], [], set()
    for path in sorted(RECONSTRUCT.glob("*.py")):
        mod_name = path.stem
        if mod_name == "tuning":
            continue
        mod = importlib.import_module(f"reflecto.reconstruct.{mod_name}")
        for name in _defined_constants(path):
            value = getattr(mod, name)
            if not _numeric(value):
                continue
            if (mod_name, name) in NOT_TUNED:
                seen.add((mod_name, name))
                continue
            if isinstance(value, dict):
                keys = {f"{name}[{k}]": v for k, v in value.items()}
            else:
                keys = {name: value}
            for key, v in keys.items():
                if (mod_name, key) not in aliases:
                    stray.append(f"reconstruct/{mod_name}.py: {key} = {v!r}")
                    continue
                seen.add((mod_name, key))
                stage, field, _ = aliases[(mod_name, key)]
                expected = getattr(stage, field)
                same = (v == expected and type(v) is type(expected)) if mod_name in PENDING_ALIAS else v is expected
                if not same:
                    wrong.append(f"reconstruct/{mod_name}.py: {key} = {v!r} is not {type(stage).__name__}.{field} "
                                 f"({expected!r})")
    assert not stray, "tuned numbers outside reconstruct/tuning.py (add a field, or a reason to NOT_TUNED):\n" + \
        "\n".join(stray)
    assert not wrong, "\n".join(wrong)
    reconstruct_aliases = {k for k in aliases if k[0] != "polar"}
    assert reconstruct_aliases <= seen, f"fields name constants their modules lack: {reconstruct_aliases - seen}"
    assert set(NOT_TUNED) <= seen, f"NOT_TUNED lists names that are gone: {set(NOT_TUNED) - seen}"


def test_the_polar_fields_are_the_polar_modules_values():
    assert tuning.POLAR.pole_spacing is polar.POLE_SPACING
    assert tuning.POLAR.spacing_growth is polar.SPACING_GROWTH


def test_the_fresnel_fit_shares_the_isotropic_eta_bound():
    from reflecto.reconstruct import fresnel_fit, isotropic

    assert fresnel_fit.ETA_MAX is isotropic.ETA_MAX is tuning.ISOTROPIC.eta_max


def test_settings_are_frozen_and_replace_makes_a_new_instance():
    old = tuning.ISOTROPIC
    new = dataclasses.replace(old, eta_max=20.0)
    assert new is not old and new.eta_max == 20.0 and old.eta_max == 50.0
    assert new.eta_min is old.eta_min
    with pytest.raises(dataclasses.FrozenInstanceError):
        old.eta_max = 20.0  # type: ignore[misc]
    from reflecto.reconstruct import isotropic

    assert isotropic.ETA_MAX == 50.0


def test_a_source_of_an_unknown_kind_is_refused():
    with pytest.raises(ValueError, match="source must start"):
        tuning.tuned(1.0, name="X", what="x", units="-", source="guess: it felt right")


def test_update_rewrites_a_stale_block(tmp_path):
    doc = tmp_path / "doc.md"
    doc.write_text(f"intro\n\n{tuning.BEGIN_MARKER}\n| stale |\n{tuning.END_MARKER}\n\nafter\n", encoding="utf-8")
    assert tuning.main(["--check", str(doc)]) == 1
    assert tuning.update_document(doc) is True
    text = doc.read_text(encoding="utf-8")
    assert text.startswith("intro\n\n") and text.endswith("\n\nafter\n") and tuning.constants_table() in text
    assert tuning.main(["--check", str(doc)]) == 0
    assert tuning.update_document(doc) is False
