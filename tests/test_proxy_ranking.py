"""Whether a shorter profile ranks rule candidates as the standard one does
(benchmarks/proxy_ranking.py): the differences compared, the agreement counted, the refusals."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from benchmarks.proxy_ranking import main


def _run(tables: Path, scene: str, variant: str, val: float, digest: str = "c") -> None:
    run = tables / "runs" / scene / variant / "seed0-x"
    run.mkdir(parents=True)
    (run / "train_log.csv").write_text("iteration\n")
    (run / "metrics.json").write_text(json.dumps({"validation": {"psnr": val}}))
    (run / "harness.json").write_text(json.dumps({"scene": scene, "variant": variant, "seed": 0, "status": "ok",
                                                  "code_digest": digest * 64, "metrics": {"psnr": val - 1}}))


def _tables(root: Path, values: dict[str, tuple[float, float, float]], digest: str = "c") -> Path:
    for scene, (full, thermal, clear) in values.items():
        for variant, v in (("full", full), ("start-thermal", thermal), ("start-clear-views", clear)):
            _run(root, scene, variant, v, digest)
    return root


def test_a_proxy_that_orders_the_differences_alike_agrees(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Differences from Full, standard: (+2, -1), (+0.5, +0.2), (-1, -0.5); the proxy's: (+1.5, -0.5),
    (+0.3, -0.6), (-0.8, +0.1). Ranks 6, 1.5, 5, 4, 1.5, 3 against 6, 3, 5, 2, 1, 4: Spearman
    13.5 / sqrt(17 x 17.5) = 0.78."""
    standard = _tables(tmp_path / "s", {"a": (20, 22, 19), "b": (25, 25.5, 25.2), "c": (18, 17, 17.5)})
    proxy = _tables(tmp_path / "p", {"a": (15, 16.5, 14.5), "b": (19, 19.3, 18.4), "c": (14, 13.2, 14.1)})
    out = tmp_path / "ranking.csv"
    assert main(["--standard", str(standard), "--proxy", str(proxy), "--out", str(out),
                 "--variants", "full,start-thermal,start-clear-views"]) == 0
    text = capsys.readouterr().out
    assert "3 scenes, 2 candidate(s) against full" in text
    assert "Spearman of the differences from full: 0.78" in text
    assert "same best variant on 2 of 3 scenes" in text           # c: the proxy picks start-clear-views
    assert "standard ranking by the mean: start-thermal 21.50, full 21.00, start-clear-views 20.57" in text
    with open(out) as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 9 and {r["variant"] for r in rows} == {"full", "start-thermal", "start-clear-views"}


def test_unfinished_or_mismatched_tables_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    standard = _tables(tmp_path / "s", {"a": (20, 22, 19)})
    other = _tables(tmp_path / "o", {"a": (20, 22, 19)}, digest="d")
    args = ["--variants", "full,start-thermal", "--out", str(tmp_path / "x.csv")]
    assert main(["--standard", str(standard), "--proxy", str(other)] + args) == 2
    assert "compare one trainer" in capsys.readouterr().err
    _run(tmp_path / "p", "b", "full", 10.0)
    assert main(["--standard", str(standard), "--proxy", str(tmp_path / "p")] + args) == 2
    assert "no scene has every variant finished under both profiles" in capsys.readouterr().err
    assert main(["--standard", str(standard), "--proxy", str(standard), "--variants", "full"]) == 2
    assert "at least one candidate" in capsys.readouterr().err
