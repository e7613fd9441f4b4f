"""The felt opposition scan (docs/scripts/felt_opposition_scan.py): each variant changes what it says and
nothing else, its detectors are on the rings, and the note's command runs on a tiny budget."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import math
import re
import shlex
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
NOTE = ROOT / "docs" / "notes" / "felt-structure.md"


def _scan():
    here = ROOT / "docs" / "scripts"
    for name in ("render_figures", "felt_opposition_scan"):
        spec = importlib.util.spec_from_file_location(name, here / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return module


def _differences(a, b) -> set[str]:
    out = set()
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if x is y:
            continue
        if dataclasses.is_dataclass(x) and dataclasses.is_dataclass(y):
            out |= {f"{f.name}.{k}" for k in _differences(x, y)}
        elif x != y:
            out.add(f.name)
    return out


def test_each_variant_changes_one_parameter_of_the_preset_by_its_factor():
    s = _scan()
    from simulate.config import load_config

    base = load_config(s.CONFIG)
    wl = np.array([450.0, 550.0, 650.0])
    expected = {"preset": set(), "dye-x3": {"dye.params"}, "dye-x0.3": {"dye.params"},
                "rms-slope-x2": {"rms_slope"}, "rms-slope-x0.5": {"rms_slope"},
                "transmission-smooth": {"transmission_rms_slope", "transmission_rms_slope_around"},
                "transmission-x2": {"transmission_rms_slope", "transmission_rms_slope_around"},
                "spread-10": {"structure.felt_spread_deg"}, "spread-2": {"structure.felt_spread_deg"},
                "punched-0.2": {"structure.felt_normal_fraction"}, "layers-5": {"structure.layers"},
                "n-1.6": {"n_host"}, "n-1.8": {"n_host"},
                "scatterers-x10+rms-slope-x2": {"particles.volume_fraction", "rms_slope"},
                "n-1.8+rms-slope-x2": {"n_host", "rms_slope"},
                "scatterers-x30+dye-x3": {"particles.volume_fraction", "dye.params"},
                "red-clear": {"dye.params"}, "red-x10": {"dye.params"},
                "blend-red": {"populations"}, "blend-red-x4": {"populations"}, "blend-red-x2": {"populations"},
                "ring-1.5": {"dye_profile", "dye_depth_um", "dye.params"},
                "core-4.1": {"dye_profile", "dye_depth_um", "dye.params"}}
    placed = {"scatterer_profile", "scatterer_depth_um", "particles.volume_fraction"}
    expected.update({name: placed for name in ("skin-0.5", "skin-1.5", "skin-3", "scatterers-core-4.1", "skin-1.5-x10",
                                               "skin-0.5-x10", "skin-1.5-x30")})
    expected.update({name: placed | expected["core-4.1"] for name in ("sheath-1.5", "sheath-1.5-x10")})
    for name in s.VARIANTS:
        cfg, shown = s.variant_config(name, base)
        if name.startswith("scatterers-x") and "+" not in name:
            factor = float(name.removeprefix("scatterers-x"))
            assert _differences(cfg, base) == {"particles.volume_fraction"}
            assert cfg.particles.volume_fraction == pytest.approx(factor * base.particles.volume_fraction)
            assert shown == {"particles.volume_fraction": cfg.particles.volume_fraction}
            continue
        assert _differences(cfg, base) == expected[name], name
        assert bool(shown) == (name != "preset")
        if name.startswith("dye-x"):
            factor = float(name.removeprefix("dye-x"))
            np.testing.assert_allclose(cfg.dye(wl), factor * base.dye(wl), rtol=1e-12)
    # a red population: the knots above 600 nm only; the blends: two populations of those dyes, by share
    knots = np.array(base.dye.params["wavelength_nm"])
    red = s.variant_config("red-x10", base)[0]
    np.testing.assert_allclose(red.dye(knots), np.where(knots > 600, 10.0, 1.0) * base.dye(knots), rtol=1e-12)
    blend = s.variant_config("blend-red", base)[0]
    assert [p.share for p in blend.populations] == [0.5, 0.5]
    assert blend.populations[1].dye == red.dye and blend.populations[0].dye == s.variant_config("red-clear", base)[0].dye
    # the dye placed in a ring keeps the fiber's amount: its coefficient over the ring's share of the section
    ring = s.variant_config("ring-1.5", base)[0]
    share = 1.0 - ((base.radius_um - 1.5) / base.radius_um) ** 2
    assert (ring.dye_profile, ring.dye_depth_um) == ("ring", 1.5)
    np.testing.assert_allclose(share * ring.dye(wl), base.dye(wl), rtol=1e-12)
    # the scatterers placed in a skin or a core keep the fiber's amount (times the factor): the volume fraction over
    # their share of the section; a sheath puts the dye below the skin of scatterers
    for name, profile, depth, factor in (("skin-1.5", "skin", 1.5, 1.0), ("scatterers-core-4.1", "core", 4.1, 1.0),
                                         ("skin-1.5-x10", "skin", 1.5, 10.0), ("sheath-1.5-x10", "skin", 1.5, 10.0)):
        cfg, shown = s.variant_config(name, base)
        inner = ((base.radius_um - depth) / base.radius_um) ** 2
        share = 1.0 - inner if profile == "skin" else inner
        assert (cfg.scatterer_profile, cfg.scatterer_depth_um) == (profile, depth)
        assert cfg.fiber(wl).scatterer_radius_um == pytest.approx(base.radius_um - depth)
        assert share * cfg.particles.volume_fraction == pytest.approx(factor * base.particles.volume_fraction)
        assert shown["fiber.scatterer_profile"] == profile and shown["fiber.scatterer_depth_um"] == depth
    sheath = s.variant_config("sheath-1.5", base)[0]
    assert (sheath.dye_profile, sheath.dye_depth_um) == ("core", 1.5)
    np.testing.assert_allclose(((base.radius_um - 1.5) / base.radius_um) ** 2 * sheath.dye(wl), base.dye(wl),
                               rtol=1e-12)
    assert s.variant_config("rms-slope-x2", base)[0].rms_slope == pytest.approx(2 * base.rms_slope)
    both, shown = s.variant_config("scatterers-x10+rms-slope-x2", base)
    assert both.rms_slope == pytest.approx(2 * base.rms_slope)
    assert both.particles.volume_fraction == pytest.approx(10 * base.particles.volume_fraction)
    assert set(shown) == {"particles.volume_fraction", "surface.rms_slope"}
    assert s.variant_config("n-1.8+rms-slope-x2", base)[1] == {"fiber.n_host": 1.8, "surface.rms_slope": 2 * base.rms_slope}
    turbid, shown = s.variant_config("scatterers-x30+dye-x3", base)
    assert turbid.particles.volume_fraction == pytest.approx(30 * base.particles.volume_fraction)
    np.testing.assert_allclose(turbid.dye(wl), 3.0 * base.dye(wl), rtol=1e-12)
    assert set(shown) == {"particles.volume_fraction", "fiber.dye.log10_per_um"}
    for n in (1.6, 1.8):
        cfg, shown = s.variant_config(f"n-{n:g}", base)
        assert cfg.n_host == n and cfg.fiber(wl).n_host == n and shown == {"fiber.n_host": n}
    assert s.variant_config("spread-10", base)[0].structure.felt_spread_deg == 10.0
    smooth = s.variant_config("transmission-smooth", base)[0]
    assert smooth.transmission_rms_slope == 0.0 and smooth.transmission_rms_slope_around is None


def test_the_detectors_lie_on_the_rings_about_the_retro_direction():
    s = _scan()
    from simulate.fabric import directions_deg

    for ti in s.INCIDENCES_DEG:
        d = np.array(s.detectors(ti))
        w = directions_deg(d[:, 0], d[:, 1])
        retro = directions_deg(np.array([ti]), np.array([0.0]))[0]
        ang = np.degrees(np.arccos(np.clip(w @ retro, -1.0, 1.0)))
        n = s.RING_POINTS
        np.testing.assert_allclose(ang[:n], 6.0, atol=1e-9)
        np.testing.assert_allclose(ang[n:2 * n], 30.0, atol=1e-9)
        np.testing.assert_allclose(w[-1], [0.0, 0.0, 1.0], atol=1e-12)
        # spread evenly round the ring: the azimuths' mean vector vanishes
        assert np.linalg.norm((w[:n] - math.cos(math.radians(6.0)) * retro).sum(0)) < 1e-9


def _note_command() -> list[str]:
    text = NOTE.read_text(encoding="utf-8")
    lines = [line for block in re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.S | re.M)
             for line in block.splitlines() if line.startswith("python docs/scripts/felt_opposition_scan.py")]
    assert lines, "the note shows the scan's command"
    return shlex.split(lines[0].split(" #")[0])[2:]


def test_the_note_s_command_runs_on_a_tiny_budget(tmp_path):
    s = _scan()
    out = tmp_path / "scan.json"
    args = _note_command() + ["--only", "preset", "--seeds", "1", "--target-rel-err", "0.5", "--max-rays", "256",
                              "--out", str(out)]
    assert s.main(args) == 0
    rec = json.loads(out.read_text(encoding="utf-8"))
    assert rec["name"] == "felt-opposition" and rec["command"].startswith(s.COMMAND) and rec["machine"]["cpus"]
    d = rec["data"]
    assert [v["name"] for v in d["variants"]] == ["preset"] and d["complete"] is False
    assert [r["seed"] for r in d["variants"][0]["runs"]] == [0]
    # the file's ratios at the scan's directions are the note's (section 1: 550 / 650 nm)
    assert d["file"]["incidences"]["40.03"]["ratio"][1:] == pytest.approx([1.135, 1.194], abs=1e-3)
    assert d["file"]["incidences"]["27.76"]["ratio"][1:] == pytest.approx([1.151, 1.236], abs=1e-3)
    for order in ("single", "all"):
        for ti in ("40.03", "27.76"):
            r = d["variants"][0]["runs"][0]["orders"][order]["incidences"][ti]
            assert d["variants"][0]["pooled"][order][ti]["ratio"] == pytest.approx(r["ratio"], rel=1e-12)
            assert r["points"] == [12, 12]
            assert all(x > 0 for x in r["ring_6"] + r["ring_30"] + r["u_ratio"])
            np.testing.assert_allclose(np.divide(r["ring_6"], r["ring_30"]), r["ratio"], rtol=1e-9)
    # the single scattering is part of all orders: less light on every ring
    a, b = (d["variants"][0]["pooled"][o]["40.03"] for o in ("single", "all"))
    assert all(x < y for x, y in zip(a["ring_30"], b["ring_30"], strict=True))


def test_the_seeds_are_pooled_ring_by_ring_with_both_standard_errors():
    s = _scan()

    def run(r6, r30, u):
        ring = {"ring_6": r6, "ring_30": r30, "normal_view": [1.0, 1.0, 1.0], "ratio": list(np.divide(r6, r30)),
                "u_ring_6": [u] * 3, "u_ring_30": [u] * 3, "u_normal_view": [0.0] * 3}
        return {"orders": {o: {"incidences": {"40.03": ring}} for o in ("single", "all")}}

    p = s.pooled([run([1.2, 1.2, 1.2], [1.0, 1.0, 1.0], 0.02), run([1.0, 1.0, 1.0], [1.0, 1.0, 1.0], 0.02)])["all"]["40.03"]
    # the rings pooled first (1.1 over 1.0), their errors halved by sqrt 2 ...
    assert p["ratio"] == pytest.approx([1.1] * 3)
    u6, u30 = 0.02 / math.sqrt(2), 0.02 / math.sqrt(2)
    assert p["u_ratio"] == pytest.approx([1.1 * math.hypot(u6 / 1.1, u30 / 1.0)] * 3)
    # ... and the seeds' own ratios 1.2 and 1.0: standard deviation 0.1414, over sqrt 2
    assert p["u_ratio_seeds"] == pytest.approx([0.1] * 3)
    one = s.pooled([run([1.2] * 3, [1.0] * 3, 0.02)])["single"]["40.03"]
    assert one["u_ratio_seeds"] == [None] * 3 and one["ratio"] == pytest.approx([1.2] * 3)


def test_an_existing_result_is_kept_without_force_and_bad_options_are_refused(tmp_path, capsys):
    s = _scan()
    out = tmp_path / "scan.json"
    out.write_text("{}", encoding="utf-8")
    for argv, word in ((["--out", str(out)], "--force"), (["--only", "nope", "--out", str(tmp_path / "n.json")], "--only"),
                       (["--target-rel-err", "2", "--out", str(tmp_path / "n.json")], "--target-rel-err"),
                       (["--resume", "--out", str(out)], "--resume")):
        with pytest.raises(SystemExit) as exc:
            s.main(argv)
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and word in err
    assert out.read_text(encoding="utf-8") == "{}"


def test_the_single_scattering_splits_into_the_surface_s_reflection_and_the_light_through_the_fiber(tmp_path,
                                                                                                    monkeypatch, capsys):
    s = _scan()
    from simulate.raytrace import integrator

    # every shadow ray traced: the two parts' candidates are then exactly the single scattering's
    monkeypatch.setattr(integrator, "SHADOW_ROULETTE", False)
    out = tmp_path / "scan.json"
    tiny = ["--only", "preset", "--seeds", "1", "--target-rel-err", "0.5", "--max-rays", "256", "--out", str(out)]
    assert s.main(tiny) == 0
    first = json.loads(out.read_text(encoding="utf-8"))["data"]["variants"][0]
    assert set(first["runs"][0]["orders"]) == {"single", "all"}
    # --resume --split adds the two parts to the run it holds, on the same felts
    assert s.main(tiny[:-2] + ["--out", str(out), "--resume", "--split"]) == 0
    v = json.loads(out.read_text(encoding="utf-8"))["data"]["variants"][0]
    run = v["runs"][0]
    assert len(v["runs"]) == 1 and set(run["orders"]) == {"single", "all", "surface", "volume"}
    assert run["orders"]["single"] == first["runs"][0]["orders"]["single"]
    assert set(v["pooled"]) == {"single", "all", "surface", "volume"}
    for ti in ("40.03", "27.76"):
        one, surf, vol = (run["orders"][o]["incidences"][ti] for o in ("single", "surface", "volume"))
        for ring in ("ring_6", "ring_30"):
            # the same paths: the parts add up to the single scattering ...
            np.testing.assert_allclose(np.add(surf[ring], vol[ring]), one[ring], rtol=1e-9)
            # ... and both carry light at 550 and 650 nm
            assert min(surf[ring][1:]) > 0 and min(vol[ring][1:]) > 0
    # a run is added to only on the felts it was traced on: refused with one line, before any trace, file kept
    rec = json.loads(out.read_text(encoding="utf-8"))
    rec["data"]["variants"][0]["runs"][0]["felt"]["thickness_um"][0] += 1.0
    del rec["data"]["variants"][0]["runs"][0]["orders"]["surface"]
    out.write_text(json.dumps(rec), encoding="utf-8")
    kept = out.read_text(encoding="utf-8")
    traced = []
    monkeypatch.setattr("simulate.raytrace.fabric_beta", lambda *a, **k: traced.append(1))
    with pytest.raises(SystemExit) as exc:
        s.main(tiny[:-2] + ["--out", str(out), "--resume", "--split"])
    assert exc.value.code == 2 and not traced and out.read_text(encoding="utf-8") == kept
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "felts" in err and "seed 0" in err
    # the tracer's shading is restored after each part, also when a trace fails
    before = integrator.shade_groups
    with pytest.raises(RuntimeError):
        with s.only_event(0):
            assert integrator.shade_groups is not before
            raise RuntimeError("inside")
    assert integrator.shade_groups is before
    with pytest.raises(ValueError, match="event"):
        with s.only_event(2):
            pass


def test_the_lambertian_felt_scores_every_albedo_on_the_same_paths(tmp_path):
    """``--lambertian``: the preset's felts with opaque Lambertian fibers. The single scattering is the
    albedo times one geometric sum, so its columns are exactly proportional to the albedos and share one
    ratio; all orders add ``a^n`` times the n-th order's sum (the same paths), so the multiply scattered
    share grows with the albedo, strictly."""
    s = _scan()
    out = tmp_path / "scan.json"
    tiny = ["--seeds", "1", "--target-rel-err", "0.5", "--max-rays", "128", "--out", str(out), "--lambertian"]
    assert s.main(tiny) == 0
    d = json.loads(out.read_text(encoding="utf-8"))["data"]
    lamb = d["lambertian"]
    a = np.asarray(s.ALBEDOS)
    assert d["variants"] == [] and lamb["albedos"] == list(s.ALBEDOS) and [r["seed"] for r in lamb["runs"]] == [0]
    for ti in ("40.03", "27.76"):
        one, every = lamb["pooled"]["single"][ti], lamb["pooled"]["all"][ti]
        for ring in ("ring_6", "ring_30", "normal_view"):
            np.testing.assert_allclose(np.divide(one[ring], a), one[ring][-1], rtol=1e-9)
            assert all(x < y for x, y in zip(one[ring], every[ring], strict=True))
            assert np.all(np.diff(lamb["multiple_share"][ti][ring]) > 0.0)
        np.testing.assert_allclose(one["ratio"], one["ratio"][0], rtol=1e-9)
        assert set(lamb["readoff"]) == {"normal_view", "ring_6", "ring_30"}
    # resumed: the seed it holds is kept, not traced anew
    traced = []
    real = s.run_lambertian
    s.run_lambertian = lambda *a, **k: traced.append(1) or real(*a, **k)
    try:
        assert s.main(tiny[:-3] + ["--out", str(out), "--resume", "--lambertian"]) == 0
    finally:
        s.run_lambertian = real
    assert not traced and json.loads(out.read_text(encoding="utf-8"))["data"]["lambertian"]["runs"] == lamb["runs"]


def _curves(level, ratio, u_level=0.01, u_ratio=0.005):
    a = np.asarray(_scan().ALBEDOS)
    return {"all": {"40.03": {"normal_view": list(level(a)), "u_normal_view": [u_level] * a.size,
                              "ratio": list(ratio(a)), "u_ratio": [u_ratio] * a.size}}}


def test_the_albedo_readoff_finds_the_file_s_levels_on_the_curve():
    s = _scan()
    # beta = 0.5 a, ratio = 1.3 - 0.2 a; the file: 0.25 at 550 nm (a = 0.5), 0.1 at 650 nm (a = 0.2)
    lamb = _curves(lambda a: 0.5 * a, lambda a: 1.3 - 0.2 * a)
    file = {"40.03": {"normal_view": [0.05, 0.25, 0.1], "ratio": [1.0, 1.13, 1.19]}}
    r = s.albedo_readoff(lamb, file)["40.03"]
    first, second = r["at"]
    assert (first["albedo"], second["albedo"]) == pytest.approx((0.5, 0.2))
    assert (first["ratio"], second["ratio"]) == pytest.approx((1.2, 1.26))
    assert r["excess"] == pytest.approx(0.06) and r["file_excess"] == pytest.approx(0.06)
    # the level's error moves the albedo by u / slope (0.02) and the ratio by that times its slope (0.2)
    assert first["u_albedo"] == pytest.approx(0.02)
    assert first["u_ratio"] == pytest.approx(math.hypot(0.005, 0.02 * 0.2))
    assert r["u_excess"] == pytest.approx(math.hypot(first["u_ratio"], second["u_ratio"]))
    # the family at the file's 650 / 550 ratio (0.4): 0.5 pairs with 0.2; 0.2 would need 0.08, not traced
    assert r["file_level_ratio"] == pytest.approx(0.4)
    fam = {f["albedo_first"]: f for f in r["family"]}
    assert fam[0.5]["albedo_second"] == pytest.approx(0.2) and fam[0.5]["excess"] == pytest.approx(0.06)
    assert fam[0.2]["albedo_second"] is None and fam[0.2]["excess"] is None
    assert fam[1.0]["albedo_second"] == pytest.approx(0.4) and fam[1.0]["excess"] == pytest.approx(0.12)
    # a level beyond the traced albedos, or a curve that does not rise, gives no albedo
    r = s.albedo_readoff(lamb, {"40.03": {"normal_view": [0.05, 0.9, 0.1], "ratio": [1.0, 1.1, 1.2]}})["40.03"]
    assert r["at"][0] is None and r["excess"] is None
    flat = s.albedo_readoff(_curves(lambda a: 0.3 + 0.0 * a, lambda a: 1.2 + 0.0 * a), file)["40.03"]
    assert flat["at"] == [None, None]


def test_the_multiply_scattered_share_is_one_less_the_single_over_all():
    s = _scan()
    ring = {"ring_6": [0.5, 0.4], "ring_30": [0.2, 0.1], "normal_view": [1.0, 1.0]}
    every = {"ring_6": [1.0, 0.5], "ring_30": [0.4, 0.4], "normal_view": [2.0, 4.0]}
    share = s.multiple_share({"single": {"40.03": ring}, "all": {"40.03": every}})["40.03"]
    assert share == {"ring_6": pytest.approx([0.5, 0.2]), "ring_30": pytest.approx([0.5, 0.75]),
                     "normal_view": pytest.approx([0.5, 0.75])}
