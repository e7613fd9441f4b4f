"""Fabrics rendered with Mitsuba 3 from exported RGL ``.bsdf`` files, and the export checks.

Mitsuba 3 is an optional dependency (the ``render`` extra, ``pip install -e '.[render]'``); every
function imports it through :func:`require_mitsuba`, which turns its absence into one line
saying how to install it. Only the CPU *scalar* variants are used (``scalar_rgb`` for RGB files,
``scalar_spectral`` for spectral ones: Mitsuba's ``measured`` plugin accepts each file type only
in the matching variant).

Checks of an exported file against Mitsuba (:func:`mitsuba_eval`, :func:`sampling_chi2`):

- ``eval`` at direction pairs, as ``f_r cos(theta_o)`` per band;
- its ``sample`` as an importance sampler: Pearson's chi-square test of N sampled directions,
  binned on a (``cos theta_o``, ``phi_o``) grid, against the expected counts from a density
  integrated over each cell (midpoint rule on a sub-grid): either Mitsuba's own ``pdf`` (is the
  sampler what it says it is?) or the density derived from ``eval`` (``Y(f_r cos)`` normalised:
  does it sample where the BRDF is?). Cells with fewer than 5 expected samples are pooled, as in
  Mitsuba's ``mitsuba.chi2`` (whose vectorised test needs an LLVM/CUDA variant, unavailable here).

References
----------
Mitsuba 3 documentation (``measured`` BSDF; ``mitsuba.chi2.ChiSquareTest``, the binning and
pooling learned from it). W. Jakob et al., Mitsuba 3 (2022).
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["MitsubaMissing", "RenderSettings", "mitsuba_eval", "render_materials", "render_section",
           "require_mitsuba", "sampling_chi2", "write_render_set"]

INSTALL_HINT = "Mitsuba 3 is not installed: install the render extra, pip install -e '.[render]' (mitsuba==3.9.1)"


class MitsubaMissing(RuntimeError):
    """Mitsuba 3 is not importable; the message says how to install it."""


def require_mitsuba(variant: str = "scalar_rgb") -> Any:
    """The ``mitsuba`` module with ``variant`` set; :class:`MitsubaMissing` (one line) without it.

    Parameters
    ----------
    variant : str, default "scalar_rgb"
        The Mitsuba variant to set (``"scalar_rgb"`` or ``"scalar_spectral"``).

    Returns
    -------
    module
        The ``mitsuba`` module.

    Raises
    ------
    MitsubaMissing
        When Mitsuba 3 is not installed.
    """
    try:
        import mitsuba as mi
    except ImportError:
        raise MitsubaMissing(INSTALL_HINT) from None
    mi.set_variant(variant)
    return mi


def _file_is_spectral(path: str | os.PathLike) -> bool:
    from gonio.data.formats.tensor import read_tensor_file

    return "wavelengths" in read_tensor_file(path)


def load_measured(path: str | os.PathLike) -> tuple[Any, Any, np.ndarray | None]:
    """``(mitsuba, bsdf, wavelengths or None)`` for an RGL file, in the variant its type needs.

    Parameters
    ----------
    path : str or os.PathLike
        The RGL ``.bsdf`` file.

    Returns
    -------
    mitsuba : module
        The ``mitsuba`` module, in ``scalar_spectral`` for a spectral file, else ``scalar_rgb``.
    bsdf : mitsuba.BSDF
        The file loaded as Mitsuba's ``measured`` BSDF.
    wavelengths : numpy.ndarray or None
        The file's wavelengths (nm) for a spectral file, else None.

    Raises
    ------
    MitsubaMissing
        When Mitsuba 3 is not installed.
    """
    from gonio.data.formats.tensor import read_tensor_file

    fields = read_tensor_file(path)
    spectral = "wavelengths" in fields
    mi = require_mitsuba("scalar_spectral" if spectral else "scalar_rgb")
    bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
    return mi, bsdf, (np.asarray(fields["wavelengths"], float) if spectral else None)


def mitsuba_eval(path: str | os.PathLike, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Mitsuba's ``eval`` (``f_r cos theta_o``) of the file at pairs ``(N, 3)``: ``(N, bands)``.

    Spectral files are evaluated at their own wavelengths (four per call, Mitsuba's bundle).

    Parameters
    ----------
    path : str or os.PathLike
        The RGL ``.bsdf`` file.
    wi, wo : numpy.ndarray
        Incident and outgoing unit directions in the local frame (``N`` x 3; ``z`` the normal).

    Returns
    -------
    numpy.ndarray
        ``f_r cos theta_o`` (sr^-1) per pair and band (``N`` x 3 for RGB, ``N`` x wavelengths for a
        spectral file).

    Raises
    ------
    MitsubaMissing
        When Mitsuba 3 is not installed.
    """
    mi, bsdf, wl = load_measured(path)
    ctx = mi.BSDFContext()
    n_bands = 3 if wl is None else wl.size
    out = np.empty((len(wi), n_bands))
    si = mi.SurfaceInteraction3f()
    for k, (a, b) in enumerate(zip(np.asarray(wi, float), np.asarray(wo, float), strict=True)):
        si.wi = mi.Vector3f(*a)
        if wl is None:
            out[k] = list(bsdf.eval(ctx, si, mi.Vector3f(*b)))
            continue
        for start in range(0, n_bands, 4):
            chunk = wl[start:start + 4]
            si.wavelengths = mi.Spectrum(list(np.pad(chunk, (0, 4 - chunk.size), mode="edge")))
            out[k, start:start + chunk.size] = list(bsdf.eval(ctx, si, mi.Vector3f(*b)))[:chunk.size]
    return out


def _bins(wo: np.ndarray, n_cos: int, n_phi: int) -> np.ndarray:
    ic = np.clip((wo[:, 2] * n_cos).astype(int), 0, n_cos - 1)
    phi = np.mod(np.arctan2(wo[:, 1], wo[:, 0]), 2 * np.pi)
    ip = np.clip((phi / (2 * np.pi) * n_phi).astype(int), 0, n_phi - 1)
    return ic * n_phi + ip


def sampling_chi2(path: str | os.PathLike, theta_i_deg: float, *, n_samples: int = 100_000,
                  n_cos: int = 20, n_phi: int = 40, sub: int = 4, seed: int = 0,
                  against: str | tuple[str, ...] = "pdf") -> dict[str, Any]:
    """Chi-square test of Mitsuba's ``sample`` at incidence ``theta_i_deg`` (``phi_i = 0``).

    ``against``: ``"pdf"`` (Mitsuba's ``pdf``) or ``"eval"`` (the luminance of ``eval``,
    normalised by its integral over the hemisphere). Returns the statistic, degrees of freedom,
    p-value, the largest relative mismatch of the sample weight ``eval / pdf`` and the sampled
    fraction that came back invalid (zero weight). A tuple of both, ``("pdf", "eval")``, scores
    ONE draw against each and returns ``{name: result}``: the draw, the costly part, is shared.

    Parameters
    ----------
    path : str or os.PathLike
        The RGL ``.bsdf`` file.
    theta_i_deg : float
        Incidence polar angle (degrees).
    n_samples : int, default 100000
        Directions drawn.
    n_cos, n_phi : int, default 20, 40
        Bins in ``cos theta_o`` and in ``phi_o``.
    sub : int, default 4
        Sub-grid points per bin and axis of the density's midpoint rule.
    seed : int, default 0
        Seed of the random numbers fed to ``sample``.
    against : str or tuple of str, default "pdf"
        The density the draws are tested against: ``"pdf"``, ``"eval"`` or both.

    Returns
    -------
    dict
        ``chi2``, ``dof``, ``p_value``, ``weight_rel_err_max``, ``invalid_fraction`` and
        ``expected_total``; for a tuple ``against``, one such dict per name.

    Raises
    ------
    ValueError
        When ``against`` names another density.
    MitsubaMissing
        When Mitsuba 3 is not installed.
    """
    from scipy.stats import chi2 as chi2_dist

    names = (against,) if isinstance(against, str) else tuple(against)
    if not names or any(a not in ("pdf", "eval") for a in names):
        raise ValueError(f"sampling_chi2: against must be 'pdf', 'eval' or a tuple of them, not {against!r}")
    mi, bsdf, wl = load_measured(path)
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    t = np.radians(theta_i_deg)
    si.wi = mi.Vector3f(np.sin(t), 0.0, np.cos(t))
    if wl is not None:
        si.wavelengths = mi.Spectrum([550.0] * 4)
    rng = np.random.default_rng(seed)
    u = rng.random((n_samples, 3))
    wo = np.empty((n_samples, 3))
    ok = np.zeros(n_samples, bool)
    weight_err = 0.0
    for k in range(n_samples):
        bs, weight = bsdf.sample(ctx, si, float(u[k, 0]), mi.Point2f(float(u[k, 1]), float(u[k, 2])))
        w = np.asarray(list(weight), float)
        ok[k] = bool(np.any(w > 0)) and bs.pdf > 0
        wo[k] = list(bs.wo)
        if ok[k] and k < 2000:      # the weight must be eval / pdf
            ev = np.asarray(list(bsdf.eval(ctx, si, bs.wo)), float)
            weight_err = max(weight_err, float(np.max(np.abs(w * bs.pdf - ev) / np.maximum(ev, 1e-12))))
    observed = np.bincount(_bins(wo[ok], n_cos, n_phi), minlength=n_cos * n_phi).astype(float)
    # density at a sub-grid of each (cos theta, phi) cell; d omega = d(cos) d(phi)
    c = (np.arange(n_cos * sub) + 0.5) / (n_cos * sub)
    p = (np.arange(n_phi * sub) + 0.5) / (n_phi * sub) * 2 * np.pi
    cc, pp = np.meshgrid(c, p, indexing="ij")
    s = np.sqrt(1 - cc ** 2)
    dirs = np.stack([s * np.cos(pp), s * np.sin(pp), cc], axis=-1).reshape(-1, 3)
    dens = {a: np.empty(len(dirs)) for a in names}
    ylum = np.array([0.212671, 0.715160, 0.072169]) if wl is None else None
    for k, d in enumerate(dirs):
        v = mi.Vector3f(*d)
        if "pdf" in dens:
            dens["pdf"][k] = bsdf.pdf(ctx, si, v)
        if "eval" in dens:
            ev = np.asarray(list(bsdf.eval(ctx, si, v)), float)
            dens["eval"][k] = float(ev @ ylum) if ylum is not None else float(ev.mean())
    cell = (1.0 / (n_cos * sub)) * (2 * np.pi / (n_phi * sub))
    results = {}
    for a in names:
        cells = dens[a].reshape(n_cos, sub, n_phi, sub).sum(axis=(1, 3)) * cell
        if a == "eval":      # the valid samples against the normalised eval density
            cells = cells / cells.sum() * ok.mean()
        expected = cells.ravel() * n_samples
        stat, dof = _pooled_chi2(expected, observed)
        results[a] = {"chi2": stat, "dof": float(dof), "p_value": float(chi2_dist.sf(stat, dof)),
                      "weight_rel_err_max": weight_err, "invalid_fraction": float(1 - ok.mean()),
                      "expected_total": float(expected.sum())}
    return results[against] if isinstance(against, str) else results


def _pooled_chi2(expected: np.ndarray, observed: np.ndarray) -> tuple[float, int]:
    """Pearson's statistic and its degrees of freedom, the smallest expected cells pooled until each expects >= 5."""
    order = np.argsort(expected)
    e_sorted, o_sorted = expected[order], observed[order]
    pooled_e, pooled_o, acc_e, acc_o = [], [], 0.0, 0.0
    for e, o in zip(e_sorted, o_sorted, strict=True):
        acc_e += e
        acc_o += o
        if acc_e >= 5:
            pooled_e.append(acc_e)
            pooled_o.append(acc_o)
            acc_e = acc_o = 0.0
    if acc_e > 0 and pooled_e:
        pooled_e[-1] += acc_e
        pooled_o[-1] += acc_o
    pe, po = np.array(pooled_e), np.array(pooled_o)
    return float(np.sum((po - pe) ** 2 / pe)), pe.size - 1


# ---------------------------------------------------------------------------------------------
# Rendering: a cushion and a flat swatch lit from several sides (the paper's Figures 8-10)
# ---------------------------------------------------------------------------------------------

CUSHION_MESH = Path(__file__).resolve().parents[1] / "fixtures" / "render" / "cushion.ply"
#: The swatch's lights: (label, incidence deg, azimuth deg relative to the camera's azimuth).
SWATCH_LIGHTS = (("overhead", 0.0, 0.0), ("behind the camera", 60.0, 0.0),
                 ("from the side", 60.0, 90.0), ("facing the camera", 60.0, 180.0))
CAMERA_ZENITH_DEG = 45.0


@dataclass
class RenderSettings:
    """Samples per pixel, cushion image ``(width, height)``, swatch image side, seed, exposure.

    ``exposure``: one linear scale for every image, so that materials compare side by side.
    """

    spp: int = 32
    size: tuple[int, int] = (240, 180)
    swatch_size: int = 112
    seed: int = 0
    exposure: float = 1.0


@dataclass
class RenderedImage:
    """One render: which material, which scene, linear RGB ``(H, W, 3)``, seconds, spp."""

    material: str
    scene: str
    rgb: np.ndarray
    seconds: float
    spp: int


def _look_at(mi: Any, origin, target, up=(0.0, 0.0, 1.0)) -> Any:
    return mi.ScalarTransform4f().look_at(origin=list(origin), target=list(target), up=list(up))


def _render(mi: Any, scene_dict: dict, spp: int, seed: int) -> np.ndarray:
    scene = mi.load_dict(scene_dict)
    img = mi.render(scene, spp=spp, seed=seed)
    return np.array(img, dtype=float)[..., :3]


def _sensor(mi: Any, origin, target, fov: float, w: int, h: int, spp: int) -> dict:
    return {"type": "perspective", "fov": fov, "to_world": _look_at(mi, origin, target),
            "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "gaussian"},
                     "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": spp}}


def cushion_scene(mi: Any, bsdf_path: str | os.PathLike, s: RenderSettings) -> dict:
    """The cushion on a grey floor under a sky and a low key light (path tracing, 3 bounces).

    Parameters
    ----------
    mi : module
        The ``mitsuba`` module, in the variant the file needs.
    bsdf_path : str or os.PathLike
        The cushion's RGL ``.bsdf`` file.
    s : RenderSettings
        Image size and samples per pixel.

    Returns
    -------
    dict
        The scene, for ``mitsuba.load_dict``.
    """
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 3},
        "sensor": _sensor(mi, (3.0, -3.4, 2.6), (0.0, 0.0, -0.05), 34.0, s.size[0], s.size[1], s.spp),
        "cushion": {"type": "ply", "filename": str(CUSHION_MESH),
                    "bsdf": {"type": "measured", "filename": str(bsdf_path)}},
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, -0.375]).scale(8.0),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.35, 0.35, 0.35]}}},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.25, 0.25, 0.25]}},
        "sun": {"type": "directional", "direction": [-0.55, 0.35, -0.76],
                "irradiance": {"type": "rgb", "value": [2.5, 2.5, 2.5]}},
    }


def swatch_scene(mi: Any, bsdf_path: str | os.PathLike, incidence_deg: float, azimuth_deg: float,
                 s: RenderSettings) -> dict:
    """A flat swatch seen at CAMERA_ZENITH_DEG, lit by one directional light (direct lighting).

    Parameters
    ----------
    mi : module
        The ``mitsuba`` module, in the variant the file needs.
    bsdf_path : str or os.PathLike
        The swatch's RGL ``.bsdf`` file.
    incidence_deg : float
        The light's polar angle from the swatch's normal (degrees).
    azimuth_deg : float
        The light's azimuth relative to the camera's (degrees; 0 behind the camera).
    s : RenderSettings
        Image size and samples per pixel.

    Returns
    -------
    dict
        The scene, for ``mitsuba.load_dict``.
    """
    cz = np.radians(CAMERA_ZENITH_DEG)
    cam = (0.0, -4.0 * np.sin(cz), 4.0 * np.cos(cz))          # camera azimuth: -y
    ti, az = np.radians(incidence_deg), np.radians(azimuth_deg - 90.0)
    to_light = np.array([np.sin(ti) * np.cos(az), np.sin(ti) * np.sin(az), np.cos(ti)])
    return {
        "type": "scene",
        "integrator": {"type": "direct"},
        "sensor": _sensor(mi, cam, (0.0, 0.0, 0.0), 24.0, s.swatch_size, s.swatch_size, s.spp),
        "swatch": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale([1.6, 1.6, 1.0]), "bsdf": {"type": "measured", "filename": str(bsdf_path)}},
        "light": {"type": "directional", "direction": list(-to_light),
                  "irradiance": {"type": "rgb", "value": [3.0, 3.0, 3.0]}},
    }


def render_materials(materials: Sequence[tuple[str, str | os.PathLike]], settings: RenderSettings | None = None,
                     *, progress: Any = print) -> list[RenderedImage]:
    """Render each ``(label, file.bsdf)``: the cushion, then the swatch under :data:`SWATCH_LIGHTS`.

    ``progress`` receives one line per image (label, scene, seconds).

    Parameters
    ----------
    materials : sequence of (str, path)
        Each material's label and RGL ``.bsdf`` file.
    settings : RenderSettings, optional
        Sizes, samples per pixel, seed and exposure (default :class:`RenderSettings`).
    progress : callable, default print
        Called with one line per image; None or False for silence.

    Returns
    -------
    list of RenderedImage
        The images, material by material, the cushion first.

    Raises
    ------
    MitsubaMissing
        When Mitsuba 3 is not installed.
    """
    s = settings or RenderSettings()
    out: list[RenderedImage] = []
    total = len(materials) * (1 + len(SWATCH_LIGHTS))
    for label, path in materials:
        mi, _bsdf, _wl = load_measured(path)     # the variant the file needs
        jobs = [("cushion", cushion_scene(mi, path, s))]
        jobs += [(f"swatch, light {name}", swatch_scene(mi, path, inc, az, s)) for name, inc, az in SWATCH_LIGHTS]
        for scene_name, scene in jobs:
            started = time.perf_counter()
            rgb = _render(mi, scene, s.spp, s.seed)
            seconds = time.perf_counter() - started
            out.append(RenderedImage(label, scene_name, rgb, seconds, s.spp))
            if progress:
                progress(f"render {len(out)}/{total}: {label}, {scene_name} ({rgb.shape[1]} x {rgb.shape[0]}, "
                         f"{s.spp} spp, {mi.variant()}): {seconds:.1f} s")
    return out


def to_srgb8(rgb: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB (clipped), the display transfer of IEC 61966-2-1.

    Parameters
    ----------
    rgb : numpy.ndarray
        Linear RGB values (any shape, 1 the white).
    exposure : float, default 1
        Linear scale applied before the transfer.

    Returns
    -------
    numpy.ndarray
        ``uint8`` values of the same shape.
    """
    x = np.clip(np.asarray(rgb, float) * exposure, 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (srgb * 255 + 0.5).astype(np.uint8)


def write_render_set(images: Sequence[RenderedImage], out_dir: str | os.PathLike,
                     settings: RenderSettings | None = None) -> dict:
    """Write the renders: individual PNGs, one side-by-side sheet (rows: materials) and ``render.json``.

    They are written together (:func:`gonio.data.write_files_together`): a set that cannot be
    written (a full disk) is one :class:`~compare.errors.CompareError` line and leaves ``out_dir``
    as it was.

    Parameters
    ----------
    images : sequence of RenderedImage
        The renders, as :func:`render_materials` returns them.
    out_dir : str or os.PathLike
        The folder written into.
    settings : RenderSettings, optional
        The settings the images were rendered with (their exposure is applied).

    Returns
    -------
    dict
        The content of ``render.json``: the sheet's file, each image's file, material, scene,
        seconds, spp and size, the caption, the total seconds and the settings.

    Raises
    ------
    CompareError
        When the files cannot be written.
    """
    import io
    import json

    import matplotlib

    from gonio.data import write_files_together

    from .errors import CompareError
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = settings or RenderSettings()
    out = Path(out_dir)
    written: dict[str, bytes] = {}
    labels = list(dict.fromkeys(im.material for im in images))
    scenes = list(dict.fromkeys(im.scene for im in images))
    files = []
    for im in images:
        name = f"{labels.index(im.material)}_{scenes.index(im.scene)}.png"
        buffer = io.BytesIO()
        plt.imsave(buffer, to_srgb8(im.rgb, s.exposure), format="png")
        written[name] = buffer.getvalue()
        files.append({"file": name, "material": im.material, "scene": im.scene, "seconds": round(im.seconds, 2),
                      "spp": im.spp, "size": [int(im.rgb.shape[1]), int(im.rgb.shape[0])]})
    widths = [2.2 if sc == "cushion" else 1.3 for sc in scenes]
    fig, axes = plt.subplots(len(labels), len(scenes), figsize=(sum(widths) + 0.4, 1.55 * len(labels) + 0.7),
                             gridspec_kw={"width_ratios": widths}, squeeze=False)
    for im in images:
        ax = axes[labels.index(im.material), scenes.index(im.scene)]
        ax.imshow(to_srgb8(im.rgb, s.exposure))
    for r, label in enumerate(labels):
        for c, scene in enumerate(scenes):
            ax = axes[r, c]
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(scene.replace("swatch, light ", "light "), fontsize=7)
        axes[r, 0].set_ylabel(label, fontsize=7)
    total = sum(im.seconds for im in images)
    caption = caption_text(images, s)
    fig.text(0.01, 0.01, caption, fontsize=6, va="bottom", wrap=True)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    sheet = io.BytesIO()
    fig.savefig(sheet, format="png", dpi=110)
    plt.close(fig)
    written["render_sheet.png"] = sheet.getvalue()
    info = {"sheet": "render_sheet.png", "images": files, "caption": caption, "seconds_total": round(total, 2),
            "settings": {"spp": s.spp, "cushion": [s.size[0], s.size[1]], "swatch": [s.swatch_size] * 2,
                         "seed": s.seed, "exposure": s.exposure, "camera_zenith_deg": CAMERA_ZENITH_DEG,
                         "swatch_lights": [list(x) for x in SWATCH_LIGHTS]}}
    written["render.json"] = (json.dumps(info, indent=2) + "\n").encode("utf-8")
    try:
        write_files_together(out, written)
    except OSError as exc:
        raise CompareError(f"cannot write the render into {out}: {exc.strerror or exc} (writing {exc.filename}); "
                           "nothing of it was written and the folder is as it was: free space or choose another "
                           "--out") from exc
    return info


def caption_text(images: Sequence[RenderedImage], s: RenderSettings) -> str:
    """The caption of the render sheet: the renderer, each scene's size, lighting and time per image.

    Parameters
    ----------
    images : sequence of RenderedImage
        The renders.
    s : RenderSettings
        The settings they were rendered with.

    Returns
    -------
    str
        The caption, one sentence ending in a full stop.
    """
    total = sum(im.seconds for im in images)
    per = {sc: np.mean([im.seconds for im in images if im.scene == sc]) for sc in dict.fromkeys(im.scene for im in images)}
    cushion = per.pop("cushion", None)
    swatch = np.mean(list(per.values())) if per else None
    parts = [f"Mitsuba 3 (scalar variants, CPU), {s.spp} spp"]
    if cushion is not None:
        parts.append(f"cushion {s.size[0]}x{s.size[1]} px, path tracing (3 bounces), {cushion:.1f} s/image")
    if swatch is not None:
        parts.append(f"swatch {s.swatch_size}x{s.swatch_size} px seen at {CAMERA_ZENITH_DEG:g} deg, one "
                     f"directional light at 60 deg (overhead: 0 deg), direct lighting, {swatch:.1f} s/image")
    parts.append(f"{len(images)} images in {total:.1f} s; same exposure for every material")
    return "; ".join(parts) + "."


def render_section(render_dir: str | os.PathLike) -> str:
    """HTML (a ``<section>``) embedding the sheet written by :func:`write_render_set`, captioned.

    Without a render (no ``render.json``) it says how to make one; the report is otherwise unchanged.

    Parameters
    ----------
    render_dir : str or os.PathLike
        The folder :func:`write_render_set` wrote.

    Returns
    -------
    str
        The section's HTML.
    """
    import base64
    import html
    import json

    d = Path(render_dir)
    meta = d / "render.json"
    if not meta.is_file():
        return ("<section id='renders'><h2>Renders</h2><p>No renders: run <code>compare render FILE.bsdf ... "
                "--out DIR</code> (needs the render extra: <code>pip install -e '.[render]'</code>).</p></section>")
    info = json.loads(meta.read_text())
    data = base64.b64encode((d / info["sheet"]).read_bytes()).decode("ascii")
    return ("<section id='renders'><h2>Renders</h2><figure>"
            f"<img alt='renders' src='data:image/png;base64,{data}' style='max-width:100%'>"
            f"<figcaption>{html.escape(info['caption'])}</figcaption></figure></section>")
