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


def test_load_resume_state_reads_last_pt_or_names_the_file(tmp_path):
    import pytest

    from cliport.errors import TrainError
    from cliport.utils.files import save_torch
    from cliport.utils.run_dir import load_resume_state

    run = RunDir(str(tmp_path))
    (tmp_path / "checkpoints").mkdir()
    save_torch({"trainer": {"step": 7, "trained_s": 1.5}}, run.checkpoint("last"))
    assert load_resume_state(run.checkpoint("last")) == {"step": 7, "trained_s": 1.5}
    save_torch({"agent": "transporter_only"}, run.checkpoint("last"))
    with pytest.raises(TrainError, match="last.pt holds no trainer state"):
        load_resume_state(run.checkpoint("last"))
