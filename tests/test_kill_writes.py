"""Issue 16: every multi-file output survives SIGKILL mid-write: afterwards the output is the old
version or the new one, whole (never a mix), and no temp file is left once the next writer has
swept the temps of dead writers."""

from __future__ import annotations

import pytest

from _kill_writers import KINDS, check, kill_during_write, leftovers, sweep

DELAYS = {"save_pretrained": 0.3, "synth_site": 0.2, "calibrate_report": 0.15, "export_ros": 0.05, "export_opencalib": 0.05, "cache": 0.1}


@pytest.mark.parametrize("kind", KINDS)
def test_kill_during_write_leaves_a_whole_output(tmp_path, kind):
    out = tmp_path / "out"
    kill_during_write(kind, out, DELAYS[kind])
    whole, detail = check(kind, out)
    assert whole, f"{kind}: {detail}"
    sweep(out)
    assert leftovers(out) == []
