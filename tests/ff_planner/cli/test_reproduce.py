"""ff-reproduce's command line: errors are one line on stderr, never a traceback."""
from __future__ import annotations

from ff_planner.cli.reproduce import main


def test_main_reports_unwritable_output(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["--out", str(blocker / "sub"), "--only", "fig3"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("ff-reproduce: error") and "Traceback" not in err
