"""read_train_log: the rows of an attempt stopped and resumed from an earlier checkpoint are
dropped, so curves never step back in iteration."""
from __future__ import annotations

from pathlib import Path

from contracts.train_log import read_train_log


def test_rows_redone_after_a_resume_are_dropped(tmp_path: Path) -> None:
    # Stage 2 ran to 30 and finished; Stage 3 reached 30 and stopped; its checkpoint was at 10,
    # so the resumed attempt logs 20 and 30 again (its wall_s continues from the stopped one's).
    rows = [(2, 10, 1.0), (2, 20, 2.0), (2, 30, 3.0), (3, 10, 4.0), (3, 20, 5.0), (3, 30, 6.0),
            (3, 20, 7.5), (3, 30, 8.5), (3, 40, 9.5)]
    log = tmp_path / "train_log.csv"
    log.write_text("stage,iteration,wall_s,test_psnr\n" + "".join(f"{s},{i},{w},\n" for s, i, w in rows))
    kept = [(int(r["stage"]), int(r["iteration"]), float(r["wall_s"])) for r in read_train_log(log)]
    assert kept == [(2, 10, 1.0), (2, 20, 2.0), (2, 30, 3.0), (3, 10, 4.0), (3, 20, 7.5), (3, 30, 8.5), (3, 40, 9.5)]


def test_a_log_without_resume_is_read_whole(tmp_path: Path) -> None:
    log = tmp_path / "train_log.csv"
    log.write_text("stage,iteration,wall_s,test_psnr\n2,10,1.0,\n3,10,2.0,20.5\n")
    assert [r["test_psnr"] for r in read_train_log(log)] == ["", "20.5"]
