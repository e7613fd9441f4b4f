"""`compare render`: Mitsuba 3 renders of RGL .bsdf files, the report section, and the missing extra."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fabric_optics.cli.compare import main as compare_main
from gonio.data.bsdf_export import export_bsdf, incidence_nodes

REPO = Path(__file__).resolve().parents[2]
FELT = REPO / "fixtures" / "real" / "acrylic_felt_green_rgb.bsdf"
MEASURED = REPO / "fixtures" / "analytic" / "measured_red"


@pytest.fixture(scope="module")
def red_glossy(tmp_path_factory):
    """A red Lambertian with a white glossy lobe towards the mirror direction (RGB)."""
    def beta(wi, wo):
        mirror = wi * np.array([-1.0, -1.0, 1.0])
        lobe = 2.0 * np.clip(np.sum(mirror * wo, axis=-1), 0, 1) ** 30
        return np.array([0.6, 0.05, 0.08])[None, :] + lobe[:, None]
    path = tmp_path_factory.mktemp("render") / "red.bsdf"
    export_bsdf(beta, path, res=24, theta_i_deg=incidence_nodes(8), description="red glossy")
    return path


def test_render_set_side_by_side(tmp_path, red_glossy, capsys):
    pytest.importorskip("mitsuba")
    out = tmp_path / "r"
    assert compare_main(["render", str(FELT), str(red_glossy), "--out", str(out), "--spp", "4",
                         "--size", "64x48", "--swatch-size", "40"]) == 0
    said = capsys.readouterr().out
    assert "10 images" in said
    info = json.loads((out / "render.json").read_text())
    assert info["settings"]["spp"] == 4 and len(info["images"]) == 10
    assert "4 spp" in info["caption"] and " s/image" in info["caption"]
    import matplotlib.image as mpimg

    def mean_rgb(material, scene):
        entry = next(e for e in info["images"] if e["material"].startswith(material) and e["scene"] == scene)
        img = mpimg.imread(out / entry["file"])[..., :3]
        return img.reshape(-1, 3).mean(axis=0)
    felt = mean_rgb("Green acrylic felt", "swatch, light overhead")
    red = mean_rgb("red glossy", "swatch, light overhead")
    assert felt[1] > felt[0] and felt[1] > felt[2]       # the felt renders green
    assert red[0] > 2 * red[1] and red[0] > 2 * red[2]    # the red export renders red
    # the glossy lobe: lit from the far side the swatch turns towards white (less saturated)
    facing = mean_rgb("red glossy", "swatch, light facing the camera")
    sat = lambda c: 1 - c.min() / c.max()                  # noqa: E731
    assert sat(facing) < sat(red) - 0.1
    assert (out / "render_sheet.png").stat().st_size > 1000


def test_spectral_file_renders_in_the_spectral_variant(tmp_path, capsys):
    pytest.importorskip("mitsuba")
    from fabric_optics.cli.gonio import main as gonio_main

    src = tmp_path / "m.bsdf"
    assert gonio_main(["export", str(MEASURED), "--out", str(src), "--resolution", "16", "--incidences", "6"]) == 0
    out = tmp_path / "r"
    assert compare_main(["render", str(src), "--out", str(out), "--spp", "2", "--size", "32x24",
                         "--swatch-size", "24", "--label", "analytic red"]) == 0
    assert "scalar_spectral" in capsys.readouterr().out


def test_render_section_embeds_the_sheet(tmp_path, red_glossy):
    pytest.importorskip("mitsuba")
    from compare.render import RenderSettings, render_materials, render_section, write_render_set

    s = RenderSettings(spp=2, size=(32, 24), swatch_size=24)
    lines: list[str] = []
    images = render_materials([("red", red_glossy)], s, progress=lines.append)
    assert len(lines) == 5 and lines[0].startswith("render 1/5: red, cushion")
    write_render_set(images, tmp_path, s)
    html = render_section(tmp_path)
    assert "data:image/png;base64," in html and "2 spp" in html
    assert "pip install" in render_section(tmp_path / "nothing")


def test_without_mitsuba_one_line_how_to_install(tmp_path, red_glossy):
    """`import mitsuba` failing (simulated) -> exit 2 and one line naming the extra."""
    code = ("import sys; sys.modules['mitsuba'] = None\n"
            "from fabric_optics.cli.compare import main\n"
            f"sys.exit(main(['render', {str(red_glossy)!r}, '--out', {str(tmp_path / 'r')!r}]))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO,
                         env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"})
    assert run.returncode == 2
    assert run.stderr.count("\n") == 1 and "pip install -e '.[render]'" in run.stderr
    assert "Traceback" not in run.stderr


def test_cushion_fixture_is_what_the_script_makes(tmp_path):
    """The shipped mesh is what fixtures/render/make_meshes.py makes: the same header and faces byte for
    byte, the same vertices and normals to float32 rounding. (The normals at the two poles are 0 in x and y
    by symmetry; the computed ones are cancellation residue of ~1e-12 whose last bits vary with the numpy
    build and CPU, so the vertex block is not byte-identical across machines.)"""
    import importlib.util

    import trimesh

    spec = importlib.util.spec_from_file_location("make_meshes", REPO / "fixtures" / "render" / "make_meshes.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mesh = mod.cushion()
    data = trimesh.exchange.ply.export_ply(mesh, encoding="binary", vertex_normal=True, include_attributes=False)
    shipped = (REPO / "fixtures" / "render" / "cushion.ply").read_bytes()
    assert len(data) == len(shipped)
    start = data.index(b"end_header\n") + len(b"end_header\n")
    end = start + len(mesh.vertices) * 6 * 4                     # x y z nx ny nz, float32 each
    assert data[:start] == shipped[:start]
    assert data[end:] == shipped[end:]                          # the faces
    made, kept = (np.frombuffer(d[start:end], dtype="<f4").reshape(-1, 6) for d in (data, shipped))
    np.testing.assert_allclose(made, kept, rtol=0, atol=1e-6)
    assert mesh.is_watertight and mesh.volume > 0


def test_report_embeds_a_render_folder(tmp_path, red_glossy):
    """`compare report ... --renders DIR` puts the sheet of `compare render` into report.html."""
    pytest.importorskip("mitsuba")
    from compare.render import RenderSettings, render_materials, write_render_set

    s = RenderSettings(spp=2, size=(32, 24), swatch_size=24)
    renders = tmp_path / "renders"
    write_render_set(render_materials([("red", red_glossy)], s), renders, s)
    sims = sorted(p for p in (REPO / "fixtures" / "analytic").iterdir() if p.is_dir() and p != MEASURED)
    out = tmp_path / "report"
    assert compare_main(["report", str(MEASURED), str(sims[0]), "--out", str(out), "--renders", str(renders)]) == 0
    page = (out / "report.html").read_text()
    assert "<section id='renders'>" in page and page.count("data:image/png;base64,") >= 1
    assert "2 spp" in page
    assert compare_main(["report", str(MEASURED), str(sims[0]), "--out", str(tmp_path / "r2"), "--renders",
                         str(tmp_path / "none")]) == 2
