import os

from cliport.evaluation.published import published_scores
from cliport.study import markdown_table, plot_study, summarise_run


def test_published_lookup_maps_task_names():
    scores = published_scores("packing-boxes-pairs-seen-colors", "transporter_only", 10)
    assert [s["score"] for s in scores] == [55.2]
    ravens = published_scores("assembling-kits", "transporter_only", 100)
    assert {s["source"].split(",")[0] for s in ravens} == {"Transporter Networks paper", "CLIPort Table 6"}
    assert published_scores("put-block-in-bowl-unseen-colors", "two_stream", 1)[0]["training_steps"] == 200000
    assert published_scores("no-such-task", "two_stream", 1) == []
    assert [s["score"] for s in published_scores("packing-boxes-pairs-seen-colors", "clip_only", 10)] == [69.7]


def test_summary_table_and_plot(tmp_path):
    val = {"checkpoints": {"1000": {"mean_score": 40.0}, "2000": {"mean_score": 70.0}}, "best_step": 2000}
    run = summarise_run("block-insertion", "transporter_only", 10, {"1000": 35.0, "2000": 60.0, "5000": 80.0}, val)
    assert run["test_at_val_selected"] == 60.0 and run["test_at_last"] == 80.0 and run["best_test"] == 80.0
    results = {"task": "block-insertion", "n_steps": 5000, "runs": [run]}
    table = markdown_table(results)
    assert "| transporter_only | - | 10 | 60.0 (step 2000) | 80.0 | 80.0 | 100.0 (Transporter Networks paper" in table
    # A run trained with a recipe stands beside the papers whose code trains that way.
    ravens = summarise_run("assembling-kits", "transporter_only", 100, {"1000": 35.0}, val, "ravens")
    cliport = summarise_run("assembling-kits", "transporter_only", 100, {"1000": 35.0}, val, "cliport")
    assert [p["source"].split(",")[0] for p in ravens["published"]] == ["Transporter Networks paper"]
    assert [p["source"].split(",")[0] for p in cliport["published"]] == ["CLIPort Table 6"]
    table = markdown_table({"task": "assembling-kits", "n_steps": 1000, "runs": [ravens, cliport]})
    assert "| transporter_only | ravens | 100 |" in table and "| transporter_only | cliport | 100 |" in table
    path = str(tmp_path / "plot.png")
    plot_study(results, path)
    assert os.path.getsize(path) > 10000


def test_several_seeds_are_reported_as_mean_and_std(tmp_path):
    from cliport.study import StudyConfig, combine_seeds

    val = {"checkpoints": {"1000": {"mean_score": 40.0}, "2000": {"mean_score": 70.0}}, "best_step": 2000}
    runs = [
        {**summarise_run("block-insertion", "transporter_only", 10, {"1000": a, "2000": b}, val), "seed": seed}
        for seed, (a, b) in enumerate([(30.0, 60.0), (50.0, 80.0), (40.0, 70.0)])
    ]
    row = combine_seeds(runs)
    assert row["seeds"] == [0, 1, 2] and row["test_at_last"] == 70.0 and row["test_at_last_std"] == 10.0
    assert row["checkpoints"][0] == {"step": 1000, "val": 40.0, "test": 40.0, "val_std": 0.0, "test_std": 10.0}
    results = {"task": "block-insertion", "n_steps": 2000, "seeds": [0, 1, 2], "runs": [row]}
    table = markdown_table(results)
    assert "over 3 training seeds" in table and "| 70.0 ± 10.0 (steps 2000, 2000, 2000) | 70.0 ± 10.0 |" in table
    plot_study(results, str(tmp_path / "plot.png"))
    unvalidated = combine_seeds(
        [
            {**summarise_run("block-insertion", "transporter_only", 10, {"1000": 90.0}, {}), "seed": seed}
            for seed in (0, 1)
        ]
    )
    table = markdown_table({"task": "block-insertion", "n_steps": 1000, "seeds": [0, 1], "runs": [unvalidated]})
    assert "| - (no validation) | 90.0 ± 0.0 |" in table and "None" not in table
    config = StudyConfig(task="block-insertion", agents=["transporter_only"], n_demos=[10], n_steps=10, out="s",
                         data_dir="d", seeds=[2, 0, 1])  # fmt: skip
    assert config.training_seeds() == [0, 1, 2]
    # Each agent trains with its papers' recipes unless the study names them.
    assert config.agent_recipes("transporter_only") == ["ravens", "cliport"]
    assert config.agent_recipes("two_stream") == ["cliport"]
    one = config.train_config("transporter_only", 10, 1, "cliport")
    assert one.run_dir == "s/runs/transporter_only-cliport-n10-s1" and one.recipe == "cliport"
    legacy = StudyConfig(task="block-insertion", agents=["transporter_only"], n_demos=[1], n_steps=1, out="s",
                         data_dir="d", recipes=["legacy"])  # fmt: skip
    assert legacy.train_config("transporter_only", 1).run_dir == "s/runs/transporter_only-legacy-n1"


def test_ceiling_column_pairs_side_by_side_and_their_plot(tmp_path, monkeypatch):
    from cliport.evaluation import published
    from cliport.study import combined_table, report

    ceilings = {"assembling-kits-seq-seen-colors": {"score": 47.9, "interval": [43.0, 52.8], "episodes": 100}}
    monkeypatch.setattr(published, "blind_ceilings", lambda: ceilings)
    val = {"checkpoints": {}, "best_step": None}
    plain = summarise_run("assembling-kits", "transporter_only", 100, {"1000": 40.0, "5000": 80.0}, val, "ravens")
    seq = summarise_run("assembling-kits-seq-seen-colors", "transporter_only", 100, {"1000": 30.0}, val, "ravens")
    both = [
        {"task": "assembling-kits", "n_steps": 5000, "seeds": [0], "runs": [plain]},
        {"task": "assembling-kits-seq-seen-colors", "n_steps": 5000, "seeds": [0], "runs": [seq]},
    ]
    table = combined_table(both)
    assert "| assembling-kits | - | 80.0* / 90.4 |" in table  # no instruction, no ceiling
    assert "| assembling-kits | 80.0* / 90.4 |" in combined_table(both[:1])  # no ceiling in the table, no column
    assert "| assembling-kits-seq-seen-colors | 47.9 | 30.0* / - |" in table
    assert (
        "| transporter_only | ravens | 100 | assembling-kits | 80.0* | assembling-kits-seq-seen-colors | 30.0* | 47.9 |"
        in (table)
    )
    assert "Language-blind ceiling: 47.9 [43.0-52.8] (100 test episodes" in markdown_table(both[1])
    assert "Language-blind ceiling" not in markdown_table(both[0])
    assert report.task_pairs(["assembling-kits-seq-seen-colors", "towers-of-hanoi"]) == []
    path = tmp_path / "pairs.png"
    assert report.plot_pairs(both, str(path)) and path.stat().st_size > 10000
    assert not report.plot_pairs(both[:1], str(tmp_path / "none.png")) and not (tmp_path / "none.png").exists()
