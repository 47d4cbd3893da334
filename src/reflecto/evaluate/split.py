"""The generalization protocol: the 50 shared materials split into a tuning and a validation half.

Every constant of the reconstruction that the data, not a mechanism, had to settle
was chosen on the tuning half; the validation half is only measured. The split is
stratified by database (5 of the 10 RGL materials, 20 of the 40 MERL/NBRDF ones in
each half) and drawn by a hash, not by hand: within each database the materials are
ranked by ``crc32("reflecto-split:" + name)`` and alternate between the halves
(even ranks tune). The lists below are that draw, written out (docs/validation.md).
"""

from __future__ import annotations

import zlib
from collections.abc import Iterable

__all__ = ["TUNING", "VALIDATION", "half", "draw_split"]

TUNING = frozenset({
    "aurora_white_rgb", "aventurnine", "black-soft-plastic", "blue-fabric", "blue-metallic-paint",
    "blue-metallic-paint2", "blue-rubber", "brass", "chm_mint_rgb", "colodur_napoli_4f_rgb", "green-fabric",
    "irid_flake_paint1_rgb", "maroon-plastic", "orange-paint", "paper_white_rgb", "purple-paint",
    "specular-blue-phenolic", "specular-maroon-phenolic", "specular-white-phenolic", "steel", "tungsten-carbide",
    "violet-acrylic", "white-marble", "white-paint", "yellow-paint",
})
VALIDATION = frozenset({
    "acrylic_felt_green_rgb", "alum-bronze", "aluminium", "black-oxidized-steel", "cc_ibiza_sunset_rgb",
    "chrome-steel", "cm_military_green_rgb", "color-changing-paint2", "delrin", "hematite", "ilm_l3_37_metallic_rgb",
    "ipswich-pine-221", "light-red-paint", "natural-209", "pink-fabric2", "pink-felt", "pink-jasper", "pvc",
    "red-metallic-paint", "red-specular-plastic", "silver-paint", "specular-green-phenolic",
    "vch_golden_yellow_rgb", "violet-rubber", "white-acrylic",
})


def half(name: str) -> str:
    """``"tuning"``, ``"validation"`` or ``"other"`` (a material outside the shared 50).

    Parameters
    ----------
    name
        The material's name (its file's stem).

    Returns
    -------
    str
        ``"tuning"`` if in :data:`TUNING`, ``"validation"`` if in :data:`VALIDATION`, else ``"other"``.
    """
    return "tuning" if name in TUNING else "validation" if name in VALIDATION else "other"


def draw_split(groups: Iterable[Iterable[str]]) -> tuple[set[str], set[str]]:
    """The draw that produced :data:`TUNING` / :data:`VALIDATION`, for any groups of names.

    Within each group the names are ranked by ``crc32("reflecto-split:" + name)``; even
    ranks (0, 2, …) tune, odd ranks validate.

    Parameters
    ----------
    groups
        Groups of material names (one per database, for stratification).

    Returns
    -------
    tuple of (set of str, set of str)
        The tuning names and the validation names.
    """
    tune: set[str] = set()
    val: set[str] = set()
    for group in groups:
        ranked = sorted(group, key=lambda n: zlib.crc32(("reflecto-split:" + n).encode()))
        tune.update(ranked[0::2])
        val.update(ranked[1::2])
    return tune, val
