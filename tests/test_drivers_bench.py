"""bench-drivers CLI: bad input is a UserError (one line, exit 2), nothing measured or written."""

from __future__ import annotations

import pytest

from capm_field.cli import main as cli_main
from capm_field.errors import UserError
from sim_bench.drivers_bench import main


@pytest.mark.parametrize(
    "argv",
    [
        ["--duration", "-1", "--json", "x.json"],
        ["--duration", "abc", "--json", "x.json"],
        ["--duration", "nan", "--json", "x.json"],
        ["--duration", "1e-9", "--json", "x.json"],  # no round trip in it: a median of nothing (traceback)
        ["--duration", "5"],  # --json is required
        ["--json", "/nonexistent-dir/x.json"],
        ["--json", "x.json", "--cutoff-trials", "0"],
        ["--bogus"],
    ],
)
def test_bad_args_are_user_errors(argv, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UserError):
        main(argv)
    assert not (tmp_path / "x.json").exists()


def test_cli_exit_code_2(capsys):
    assert cli_main(["bench-drivers", "--duration", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bench-drivers" in err[0]
