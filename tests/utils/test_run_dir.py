from cliport.utils.run_dir import RunDir


def test_layout_and_checkpoint_listing(tmp_path):
    run = RunDir(str(tmp_path))
    assert not run.is_run() and not run.has_progress() and run.checkpoint_steps() == []
    (tmp_path / "checkpoints").mkdir()
    for name in ("step-001000.pt", "step-000500.pt", "last.pt", "step-12.pt", "notes.txt"):
        (tmp_path / "checkpoints" / name).write_bytes(b"")
    (tmp_path / "config.json").write_text("{}")
    assert run.checkpoint_steps() == [500, 1000] and run.is_run() and run.has_progress()
    assert run.checkpoint(500).endswith("checkpoints/step-000500.pt")
    assert run.checkpoint("last").endswith("checkpoints/last.pt")
    assert run.val.endswith("val.json") and run.eval_dir.endswith("eval")
