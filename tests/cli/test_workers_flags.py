"""--workers / --val-workers: bad counts are one clear error line, before any run folder or data is read."""

import pytest

from cliport.cli import eval as eval_cli
from cliport.cli import train as train_cli
from cliport.cli.common import run_cli


@pytest.mark.parametrize(
    "main, args, message",
    [
        (eval_cli.main, ["--run-dir", "/nonexistent", "--workers", "0"], "--workers must be >= 1, got 0"),
        (
            eval_cli.main,
            ["--run-dir", "/nonexistent", "--workers", "3", "--n-episodes", "2"],
            "--workers 3 is more than the 2 episode(s) to run; use at most 2",
        ),
        (
            train_cli.main,
            ["--task", "block-insertion", "--agent", "transporter_only", "--val-workers", "0"],
            "--val-workers must be >= 1, got 0",
        ),
        (
            train_cli.main,
            ["--task", "block-insertion", "--agent", "transporter_only", "--val-episodes", "2", "--val-workers", "5"],
            "--val-workers 5 is more than the 2 episode(s)",
        ),
        (
            train_cli.main,
            ["--task", "block-insertion", "--agent", "transporter_only", "--val-episodes", "0", "--val-workers", "2"],
            "--val-workers needs validation",
        ),
    ],
)
def test_bad_worker_counts_are_one_clear_line(tmp_path, capsys, one_error_line, main, args, message):
    if main is train_cli.main:
        args = [*args, "--run-dir", str(tmp_path / "run"), "--data-dir", str(tmp_path / "no-data")]
    with pytest.raises(SystemExit) as stop:
        run_cli(lambda: main(args))
    one_error_line(stop.value.code, capsys.readouterr().err, message, status=2)
    assert not (tmp_path / "run").exists()
