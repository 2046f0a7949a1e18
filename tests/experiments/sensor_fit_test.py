"""The sensor fit: candidates' fine detail against the real domains', the nearest chosen, and drone-v2 at it."""

import json
from pathlib import Path

import numpy as np
import pytest

from meta_sim.experiments import sensor_fit
from meta_sim.sim.sensor import get_sensor

ROOT = Path(__file__).resolve().parents[2]


def _renders(n=3, px=48, seed=0):
    """Linear images with detail at every scale (white noise over smooth shading)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        base = np.linspace(0.05, 0.3, px, dtype=np.float32)[None, :, None] * np.ones((px, 1, 3), np.float32)
        out.append(np.clip(base + 0.03 * rng.standard_normal((px, px, 3)).astype(np.float32), 0.0, None))
    return out


def test_the_fit_picks_the_candidate_nearest_to_the_real_detail_and_blur_lowers_it():
    renders = _renders()
    sharp = sensor_fit.rendered_detail(renders, get_sensor("drone").__class__(name="x", sharpen=1.0))
    soft = sensor_fit.rendered_detail(renders, get_sensor("drone").__class__(name="x", blur_px=1.2))
    assert soft < sharp
    # Real drone domains as detailed as the renders through blur 0.6 and no sharpening: that candidate wins.
    target = sensor_fit.rendered_detail(renders, get_sensor("drone"))
    fit = sensor_fit.fit_sensors(renders, {"banepa": target, "kampala": target, "rio": soft})
    assert set(fit) == {"drone", "satellite"}
    assert (fit["drone"]["fitted"]["blur_px"], fit["drone"]["fitted"]["sharpen"]) == (0.6, 0.0)
    assert fit["drone"]["fitted"]["distance"] == pytest.approx(0.0, abs=1e-6)
    assert fit["drone"]["current"]["distance"] == pytest.approx(0.0, abs=1e-6)
    assert len(fit["drone"]["grid"]) == len(sensor_fit.FIT_BLUR) * len(sensor_fit.FIT_SHARPEN)
    assert all(g["distance"] >= fit["satellite"]["fitted"]["distance"] for g in fit["satellite"]["grid"])
    assert set(fit["drone"]["domains"]) == {"banepa", "kampala"} and set(fit["satellite"]["domains"]) == {"rio"}
    table = sensor_fit.format_sensor_table({"sensors": fit, "renders": 3, "designs": 3, "tiles": 1,
                                            "space": "s", "seconds": 1.0})
    assert "| drone | banepa " in table and "| 0.6 / 0 |" in table


def test_drone_v2_has_the_published_fit():
    """The named sensor ``drone-v2`` is ``drone`` with the sharpness `make bench-sensor` found nearest."""
    published = json.loads((ROOT / "benchmarks" / "sensor.json").read_text())["sensors"]["drone"]["fitted"]
    v2, v1 = get_sensor("drone-v2"), get_sensor("drone")
    assert (v2.blur_px, v2.sharpen) == (published["blur_px"], published["sharpen"])
    assert (v2.read_noise, v2.shot_noise, v2.jpeg_quality, v2.gains) == (v1.read_noise, v1.shot_noise,
                                                                         v1.jpeg_quality, v1.gains)


def test_bench_sensor_command_writes_the_fit_and_its_table(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from meta_sim.cli import main

    renders = _renders()
    target = sensor_fit.rendered_detail(renders, get_sensor("drone"))
    result = {"sensors": sensor_fit.fit_sensors(renders, {"banepa": target, "kampala": target, "rio": target}),
              "renders": 3, "designs": 3, "tiles": 1, "space": "s", "seed": 1, "seconds": 2.0}
    monkeypatch.setattr(sensor_fit, "bench_sensor", lambda cache_dir=None, realdata=None, bars=None: result)
    out = tmp_path / "sensor.json"
    ran = CliRunner().invoke(main, ["bench", "sensor", "--no-docs", "--out", str(out)])
    assert ran.exit_code == 0, ran.output
    assert json.loads(out.read_text())["sensors"]["drone"]["fitted"] == result["sensors"]["drone"]["fitted"]
    assert "| drone | banepa " in ran.output and "| satellite | rio " in ran.output
