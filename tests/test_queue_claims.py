"""The table queue's claims (benchmarks/standard_tables_queue.sh): a live worker's claim is alive,
a dead worker's is stale, and the owner's start is the kernel's start in clock ticks after boot,
which a reset of the wall clock does not move (ps's lstart did, and two live workers then took
over each other's claims)."""
from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _functions() -> str:
    script = (ROOT / "benchmarks" / "standard_tables_queue.sh").read_text()
    found = [re.search(rf"^{name}\(\) {{.*?^}}$", script, re.S | re.M) for name in ("started_ticks", "alive")]
    assert all(found), "standard_tables_queue.sh: started_ticks() or alive() is missing"
    return "\n".join(m.group(0) for m in found)


def _bash(body: str, cwd: Path) -> str:
    done = subprocess.run(["bash", "-c", _functions() + "\n" + body], cwd=cwd, capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_a_live_claim_is_alive_and_a_dead_ones_is_stale(tmp_path: Path) -> None:
    out = _bash("""
mkdir live dead old
echo "$$ $(started_ticks $$)" > live/owner
sleep 30 & p=$!
echo "$p $(started_ticks $p)" > dead/owner
kill $p; wait $p 2>/dev/null
echo "$$ Wed Dec  2 01:23:40 2026" > old/owner
for c in live dead old; do if alive $c; then echo "$c alive"; else echo "$c stale"; fi; done
echo "ticks $(started_ticks $$) pid $$"
""", tmp_path)
    assert "live alive" in out and "dead stale" in out
    assert "old stale" in out   # an owner line in the former lstart form is never taken for alive
    ticks, pid = re.search(r"ticks (\d+) pid (\d+)", out).groups()
    # started_ticks is field 22 of /proc/PID/stat, read past a command name that may hold spaces
    assert int(ticks) > 0 and pid


def test_started_ticks_reads_field_22_past_a_command_name_with_spaces(tmp_path: Path) -> None:
    odd = tmp_path / "odd name) 1 2"   # the kernel's command name is the file's, with its spaces
    odd.write_bytes(Path("/bin/sleep").read_bytes())
    odd.chmod(0o755)
    proc = subprocess.Popen([str(odd), "30"])
    try:
        stat = Path(f"/proc/{proc.pid}/stat").read_text()
        assert "(odd name) 1 2)" in stat
        expected = stat.rsplit(")", 1)[1].split()[19]
        assert _bash(f"started_ticks {proc.pid}", tmp_path).strip() == expected
    finally:
        proc.kill()
        proc.wait()
