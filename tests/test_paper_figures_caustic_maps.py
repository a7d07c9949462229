"""Smoke test of ``paper_figures/table1_adaptive.py`` (``--quick``: about a minute, most
of it jit compilation; marked slow)."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parent.parent / "paper_figures" / "table1_adaptive.py"


def _load():
    spec = importlib.util.spec_from_file_location("paper_table1_adaptive", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_table1_adaptive_quick(tmp_path, capsys):
    module = _load()
    assert module.main(["--quick", "--out", str(tmp_path)]) == 0
    md = (tmp_path / "table1_adaptive.md").read_text()
    summary = json.loads((tmp_path / "table1_adaptive.json").read_text())
    resolutions = summary["settings"]["resolutions"]
    assert resolutions == [256, 512]
    assert [s["scene"] for s in summary["scenes"]] == ["sphere"]

    for scene in summary["scenes"]:
        rows = {(r["method"], r["photons"]): r for r in scene["rows"]}
        assert set(rows) == {(m, n) for m in ("dense", "traversal", "error") for n in resolutions}
        for n in resolutions:
            dense, traversal, error = (rows[m, n] for m in ("dense", "traversal", "error"))
            assert all(r["rendered"] for r in (dense, traversal, error))
            # the dense map shades all N^2 photons; the adaptive ones far fewer, and
            # splat a modest fraction of the view (the object covers a few percent)
            assert dense["generated"] == n * n
            assert 0 < traversal["generated"] < n * n / 2
            assert 0 < error["generated"] < n * n / 2
            assert 0.01 * n * n < traversal["splatted"] < 0.2 * n * n
            # the same photons from the same geometry buffers: footprint discard loses
            # none of the dense grid's valid photons
            assert traversal["splatted"] == dense["splatted"]
            # the error metric merges clusters: never more photons than max traversal,
            # and the same ones before the level it checks from (512^2)
            assert error["splatted"] <= traversal["splatted"]
            if n < summary["settings"]["check_from"]:
                assert error["splatted"] == traversal["splatted"]
            # counts add up over the levels; the coarse level is the 64^2 base grid
            for r in (traversal, error):
                assert sum(r["generated_per_level"]) == r["generated"]
                assert sum(r["splatted_per_level"]) == r["splatted"]
                assert r["generated_per_level"][0] == 64 * 64
                assert len(r["generated_per_level"]) == int(np.log2(n // 64)) + 1
            # one batch for the small dense rows; the adaptive ones: one per level
            assert dense["batches"] == 1
            assert traversal["batches"] >= len(traversal["generated_per_level"])
            assert traversal["peak_buffer_bytes"] < dense["peak_buffer_bytes"]
            # the images agree with the reference (image-space estimate, a small map)
            for r in (dense, traversal, error):
                assert 0.0 < r["rel_l1"] < 0.15, r
                assert r["rel_l1"] <= r["rel_l1_unblurred"] + 1e-9
                assert 0.9 < r["flux_ratio"] < 1.1
                assert r["seconds"] > 0
            assert error["rel_l1"] == pytest.approx(traversal["rel_l1"], abs=0.01)

    # the markdown table: a row per method and resolution, and the summary table
    table_rows = [line for line in md.splitlines() if line.startswith("| ")]
    for n in resolutions:
        assert sum(line.startswith(f"| {n}^2 |") for line in table_rows) == 1 + 3
        for name in module.METHOD_NAMES.values():
            assert any(line.startswith(f"| {n}^2 | {name} |") for line in table_rows)
    assert not any("not run" in line for line in table_rows)
    assert "sigma = 1 px" in md
    out = capsys.readouterr().out
    assert "Table 1" in out and str(tmp_path / "table1_adaptive.md") in out


def test_scenes_lie_above_the_receiver():
    module = _load()
    # both generators are closed and lie above the receiver (checked in `scene/scene.py`)
    for name in module.SCENES:
        scene = module.make_scene(name, module.QUICK)
        assert float(np.asarray(scene.generator.vertices)[:, 2].min()) > 0.0
    # (its error is `jc.image_error`, tested with the library)


def test_help(capsys):
    with pytest.raises(SystemExit) as exc:
        _load().main(["--help"])
    assert exc.value.code == 0
    assert "--quick" in capsys.readouterr().out
