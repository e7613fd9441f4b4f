"""Exporting a fabric model or a dataset to a renderer as an RGL ``.bsdf`` file.

:func:`export_bsdf` is ``simulate export`` (a fabric model) and ``gonio export`` (a dataset); the
file is what Mitsuba 3's ``measured`` material and pbrt-v4 read.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from fabric_optics import validate as _v
from fabric_optics.api.loading import load_config, refuse_existing
from fabric_optics.errors import InputError, typed_errors
from gonio.data.dataset import Dataset
from simulate.config import SimulationConfig

__all__ = ["export_bsdf"]


@typed_errors
def export_bsdf(source: str | os.PathLike | SimulationConfig | Dataset, path: str | os.PathLike, *,
                method: str = "summation", wavelengths_nm: Sequence[float] | None = None, rgb: bool = False,
                resolution: int = 64, incidences: int = 16, target_rel_err: float | None = None,
                seed: int | None = None, threads: int | None = None, max_photons: int | None = None,
                check_pairs: int = 0, anisotropic: int = 0, azimuths: int = 5, description: str | None = None,
                provenance: dict | None = None, force: bool = False, progress: bool = False) -> Any:
    """Write an RGL `.bsdf` file (Mitsuba 3's `measured` material, pbrt-v4) of a fabric model or a dataset.

    A renderer then shows the fabric under any light, from the same model or measurement the
    comparison judged. The tabulation's error can be measured (`check_pairs`) so that a file says
    how far it is from its model.

    Parameters
    ----------
    source : str, path, SimulationConfig or Dataset
        A fabric (a preset, a config TOML file or a loaded config), evaluated by `method`; or a
        dataset, its values interpolated (and extrapolated where it has no data: the rule is in
        the result's `.provenance["coverage"]`).
    path : str or path
        The `.bsdf` file to write.
    method : str, default "summation"
        For a fabric: `"summation"`, `"classic"` or `"mc"`.
    wavelengths_nm : sequence of float, optional
        For a fabric: the file's wavelengths, increasing (the config's by default).
    rgb : bool, default False
        For a fabric: an RGB file instead of a spectral one.
    resolution : int, default 64
        Values per axis of the tabulation (4 to 256).
    incidences : int, default 16
        Incidence nodes (2 to 64).
    target_rel_err : float, optional
        For a fabric: the Monte Carlo's relative standard error (the config's by default).
    seed : int, optional
        For a fabric: the random seed (the config's by default).
    threads : int, optional
        For a fabric: worker threads; `0` uses every core numba may.
    max_photons : int, optional
        For a fabric: upper bound on the photons of each Monte Carlo walk.
    check_pairs : int, default 0
        Measure the tabulation error at that many random direction pairs (more model evaluations).
    anisotropic : int, default 0
        1, 2 or 4: keep the model's anisotropy with `azimuths` incidence azimuths over
        360/`anisotropic` degrees; 0: isotropic.
    azimuths : int, default 5
        Incidence azimuths of an anisotropic file.
    description : str, optional
        The file's description (a dataset's).
    provenance : dict, optional
        Merged into the provenance written into a dataset's file.
    force : bool, default False
        Replace an existing file.
    progress : bool, default False
        Show a progress bar.

    Returns
    -------
    ExportResult
        `.path`, `.evaluations`, `.valid_fraction`, `.error` (with `check_pairs`), `.provenance`.

    Raises
    ------
    OutputExistsError
        `path` exists and `force` is False.
    OutputBusyError
        Another writer is writing `path` now.
    InputError
        A resolution, incidence count, method or anisotropy out of range, a source that is neither a
        config nor a dataset, or a run refused by its cost estimate.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> import fabric_optics as fo
    >>> measured = fo.read_dataset("fixtures/analytic/measured_red")
    >>> result = fo.export_bsdf(measured, Path(tempfile.mkdtemp()) / "red.bsdf", resolution=8, incidences=4)
    >>> Path(result.path).name, result.provenance["coverage"]["incidences_deg"]
    ('red.bsdf', [0.0, 30.0, 45.0, 60.0])
    """
    out = _v.out_path("path", path, file=True)
    _v.choice("method", method, ("summation", "classic", "mc"))
    _v.wavelengths("wavelengths_nm", wavelengths_nm)
    for arg, value in (("rgb", rgb), ("force", force), ("progress", progress)):
        _v.flag(arg, value)
    _v.integer("resolution", resolution, 4, 256)
    _v.integer("incidences", incidences, 2, 64)
    _v.rel_err("target_rel_err", target_rel_err)
    _v.seed("seed", seed)
    _v.threads("threads", threads)
    _v.integer("max_photons", max_photons, 1, 10**15, none=True)
    _v.integer("check_pairs", check_pairs, 0, _v.MAX_CHECK_PAIRS)
    _v.choice("anisotropic", anisotropic, (0, 1, 2, 4))
    _v.integer("azimuths", azimuths, 3, _v.MAX_AZIMUTHS)
    _v.text("description", description, none=True)
    if provenance is not None and not isinstance(provenance, dict):
        raise InputError(f"provenance: expected a dict, got {type(provenance).__name__}")
    if not isinstance(source, (Dataset, SimulationConfig, str, os.PathLike)):
        raise InputError(f"source: expected a config, preset name, path or Dataset, got {type(source).__name__}")
    with _v.claimed("path", out, file=True):
        return _export_bsdf(source, out, method=method, wavelengths_nm=wavelengths_nm, rgb=rgb,
                            resolution=resolution, incidences=incidences, target_rel_err=target_rel_err, seed=seed,
                            threads=threads, max_photons=max_photons, check_pairs=check_pairs,
                            anisotropic=anisotropic, azimuths=azimuths, description=description,
                            provenance=provenance, force=force, progress=progress)


def _export_bsdf(source: str | os.PathLike | SimulationConfig | Dataset, out: Path, *, method: str,
                 wavelengths_nm: Sequence[float] | None, rgb: bool, resolution: int, incidences: int,
                 target_rel_err: float | None, seed: int | None, threads: int | None, max_photons: int | None,
                 check_pairs: int, anisotropic: int, azimuths: int, description: str | None,
                 provenance: dict | None, force: bool, progress: bool) -> Any:
    refuse_existing(out, force, "path", file=True)
    if isinstance(source, Dataset):
        from gonio.data.bsdf_dataset import dataset_brdf, dataset_nodes
        from gonio.data.bsdf_export import export_bsdf as _export

        beta, rule = dataset_brdf(source)
        return _export(beta, out, wavelengths_nm=None if source.is_rgb else source.wavelengths_nm,
                       theta_i_deg=dataset_nodes(rule, incidences), res=resolution,
                       description=description or f"{source.name} (fabric-optics export of a measured dataset)",
                       provenance={"dataset": source.name, **(provenance or {}), "coverage": rule})
    from simulate.export import export_model

    if method not in ("summation", "classic", "mc"):
        raise InputError(f"method {method!r}: choose one of summation, classic, mc")
    if anisotropic not in (0, 1, 2, 4):
        raise InputError(f"anisotropic {anisotropic}: choose 0 (isotropic), 1, 2 or 4")
    if threads == 0:        # 0 = all that numba allows, as in simulate()
        import numba

        threads = int(numba.config.NUMBA_NUM_THREADS)
    config = load_config(source)
    _v.cost(config, config.wavelengths_nm if wavelengths_nm is None else wavelengths_nm, target_rel_err, max_photons)
    return export_model(config, method, out, wavelengths_nm=wavelengths_nm, rgb=rgb, res=resolution,
                        incidences=incidences, target_rel_err=target_rel_err, seed=seed, threads=threads,
                        max_photons=max_photons, check_pairs=check_pairs, reduction=anisotropic, n_phi_i=azimuths,
                        progress=progress)
