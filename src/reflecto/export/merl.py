"""MERL ``.binary`` export (Matusik et al. 2003; format in algorithm-reference §6.1).

A source is evaluated at every bin centre (``φ_h = 0``, the centre convention of
:func:`reflecto.sources.merl.bin_centres`) and written with the channel scales, so
reflecto's (and MERL's) reader returns exactly those values. Bins with a direction
below the horizon hold 0, never the "unmeasured" marker −1: an exported model is
defined everywhere. MERL tables are isotropic: anisotropic sources are refused unless
``allow_anisotropic`` (then the ``φ_h = 0`` slice is what gets written).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..brdf import BRDFSource
from ..errors import FileFormatError, ParameterError, short_repr, shown_path
from ..sources import merl
from .rgl import proxy_ndf


def export_merl(source: BRDFSource, path: str | Path, allow_anisotropic: bool = False,
                progress: Callable[[int], None] | None = None) -> Path:
    """Tabulate ``source`` on the MERL grid and write it atomically.

    Parameters
    ----------
    source
        Any BRDF (sr⁻¹), evaluated at the centres of the 90 × 90 × 180 (θ_h, θ_d, φ_d) bins.
    path
        The ``.binary`` file to write.
    allow_anisotropic
        Write an anisotropic source's ``φ_h = 0`` slice instead of refusing it.
    progress
        Called with the number of bins done after each chunk.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ParameterError
        For a path whose name does not end in ``.binary``, an anisotropic source without
        ``allow_anisotropic``, or a source that is negative (beyond round-off) or not finite.
    FileFormatError
        Naming ``path``, for a table reflecto's reader would refuse (its albedo or values
        implausible): nothing is written.
    """
    path = Path(path)
    if path.suffix.lower() != ".binary":
        raise ParameterError(f"{shown_path(path)}: not written, a MERL file's name must end in .binary")
    if not isinstance(allow_anisotropic, (bool, np.bool_)):
        raise ParameterError(f"allow_anisotropic must be True or False, got {short_repr(allow_anisotropic)}")
    if not allow_anisotropic and not holds_isotropic(source):
        raise ParameterError(f"{source.name} is anisotropic; MERL files hold isotropic BRDFs only "
                             "(pass allow_anisotropic to write its φ_h = 0 slice)")
    table = merl.tabulate(source, progress=progress)
    if not np.all(np.isfinite(table)):
        raise ParameterError(f"{source.name}: not finite on the MERL grid ({np.count_nonzero(~np.isfinite(table))} "
                             "values)")
    low = float(table.min())
    if low < -NEGATIVE_TOLERANCE * max(1.0, float(table.max())):
        raise ParameterError(f"{source.name}: negative on the MERL grid (down to {low:.3g} sr⁻¹): not a BRDF")
    np.maximum(table, 0.0, out=table)  # round-off below 0 (a bin written −1 would read as unmeasured)
    try:  # reflecto writes only what it reads: the reader's checks, before the file takes its name
        merl.check_table(merl.MerlBRDF.from_table(table, source.name), path)
    except FileFormatError as e:
        raise FileFormatError(path, f"not written: the file would be refused on reading ({e.problem})") from None
    return merl.write_merl_table(path, table)


#: How far below 0 a tabulated value may lie, relative to the table's largest (at least
#: 1 sr⁻¹), and count as round-off that is set to 0.
NEGATIVE_TOLERANCE = 1e-9


def holds_isotropic(source: BRDFSource) -> bool:
    """Whether a MERL table (isotropic, ``φ_h = 0``) holds ``source`` whole: it says it is
    isotropic, or its NDF (or back-scattering) is rotationally symmetric.

    Parameters
    ----------
    source
        The BRDF.

    Returns
    -------
    bool
        ``True`` where the φ_h = 0 slice stands for every azimuth.
    """
    if getattr(source, "isotropic", False):
        return True

    return proxy_ndf(source)[1]
