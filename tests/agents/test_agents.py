import math
import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from cliport.agents import PickPlaceAgent, agent_class, agent_names, make_agent
from cliport.agents.config import AgentConfig, CLIPConfig
from cliport.agents.loss import optimizer_step
from cliport.agents.registry import _make_config
from cliport.errors import ConfigError, UnknownNameError
from cliport.models.encoders.dense_clip import SIMILARITY_MAPS, instruction_phrases
from cliport.models.preprocess import raw_input

H, W = 64, 32
RED_BLOCK, GREEN_BOWL, BLUE_BLOCK, YELLOW_BOWL = (11, 7), (45, 23), (33, 23), (55, 7)


def _scene() -> dict[str, np.ndarray]:
    color = np.zeros((H, W, 3), np.uint8)
    height = np.zeros((H, W), np.float32)
    for (u, v), rgb, z in [
        (RED_BLOCK, (255, 87, 89), 0.02),
        (GREEN_BOWL, (89, 169, 79), 0.01),
        (BLUE_BLOCK, (78, 121, 167), 0.02),
        (YELLOW_BOWL, (237, 201, 72), 0.01),
    ]:
        color[u - 3 : u + 3, v - 3 : v + 3] = rgb
        height[u - 3 : u + 3, v - 3 : v + 3] = z
    return {"color": color, "height": height}


def _batch(targets: list[tuple[tuple[int, int], tuple[int, int], int, str]]) -> dict[str, object]:
    obs = _scene()
    b = len(targets)
    return {
        "color": torch.from_numpy(obs["color"])[None].repeat(b, 1, 1, 1),
        "height": torch.from_numpy(obs["height"])[None].repeat(b, 1, 1),
        "pick_pix": torch.tensor([t[0] for t in targets]),
        "place_pix": torch.tensor([t[1] for t in targets]),
        "place_rot": torch.tensor([t[2] for t in targets]),
        "lang": [t[3] for t in targets],
    }


def _hits(agent: PickPlaceAgent, target: tuple[tuple[int, int], tuple[int, int], int, str]) -> bool:
    out = agent.act(_scene(), target[3])
    return out["pick_pix"] == target[0] and out["place_pix"] == target[1] and out["place_bin"] == target[2]


def _within_a_pixel(agent: PickPlaceAgent, target: tuple[tuple[int, int], tuple[int, int], int, str]) -> bool:
    """Pick and place within a pixel of the target's, the rotation bin right up to the 6 x 6 squares' symmetry
    (they look alike every 90 degrees: 2 of 8 bins)."""
    out = agent.act(_scene(), target[3])
    near = [
        np.abs(np.subtract(out[key], pix)).max() <= 1
        for key, pix in (("pick_pix", target[0]), ("place_pix", target[1]))
    ]
    return all(near) and out["place_bin"] % 2 == target[2] % 2


def _fit(
    agent: PickPlaceAgent, targets: list, max_steps: int, check_every: int, hits: Callable[..., bool] = _hits
) -> int | None:
    """Train on one batch holding `targets` until ``hits(agent, target)`` holds for every target (checked every
    ``check_every`` steps): the step count at which it did, or None after ``max_steps``. A bound on steps rather
    than a fixed count: how many steps a fit takes moves with the CPU's float rounding."""
    batch = _batch(targets)
    optimizer = agent.make_optimizer()
    for step in range(1, max_steps + 1):
        agent.train()  # the checks act, in eval mode
        optimizer_step(agent.compute_loss, batch, optimizer)
        if step % check_every == 0 and all(hits(agent, t) for t in targets):
            return step
    return None


def test_registry_and_default_configs() -> None:
    assert {"transporter_only", "two_stream", "clip_only", "rn50_bert"} <= set(agent_names())
    assert agent_names() == sorted(agent_names())
    ts = _make_config("two_stream")
    assert isinstance(ts, CLIPConfig)
    assert (ts.n_rotations, ts.crop_size, ts.lr, ts.width, ts.clip_weights) == (36, 64, 1e-4, 1.0, "openai")
    to = _make_config("transporter_only")
    assert type(to) is AgentConfig and (to.n_rotations, to.crop_size) == (36, 64)
    assert agent_class("two_stream").uses_language and not agent_class("transporter_only").uses_language
    assert agent_class("two_stream").weight_sources == ("clip_weights",)
    assert agent_class("rn50_bert").weight_sources == ("rn50_weights", "bert_weights")
    assert agent_class("clip_only").uses_language and agent_class("rn50_bert").uses_language
    rb = _make_config("rn50_bert")
    assert (rb.rn50_weights, rb.bert_weights, rb.width) == ("imagenet", "distilbert-base-uncased", 1.0)
    assert _make_config("clip_only").semantic_encoder == "RN50-quickgelu"
    with pytest.raises(UnknownNameError, match="unknown agent 'two_steam' \\(did you mean 'two_stream'\\?\\)"):
        make_agent("two_steam")
    with pytest.raises(ConfigError, match="transporter_only has no setting\\(s\\) n_rotation \\(did you mean 'n_rot"):
        make_agent("transporter_only", {"n_rotation": 3})
    with pytest.raises(ConfigError, match="n_rotations must be int, got 'x'"):
        make_agent("transporter_only", {"n_rotations": "x"})
    for width in (0, -1):
        with pytest.raises(ConfigError, match="width must be > 0"):
            make_agent("transporter_only", {"width": width})


def test_action_targets_follow_the_place_heads_convention(tiny_config) -> None:
    from cliport.env.heightmap import pix_to_xyz
    from cliport.env.transforms import yaw_to_quat

    agent = make_agent("transporter_only", tiny_config("transporter_only"))
    height = np.zeros((320, 160), np.float32)
    pose0 = np.array([[*pix_to_xyz((12, 34), height), *yaw_to_quat(1.0)]])
    pose1 = np.array([[*pix_to_xyz((300, 5), height), *yaw_to_quat(1.0 - math.radians(45))]])
    pick, place, rot = agent.action_targets(pose0, pose1, (320, 160))
    assert pick.tolist() == [[12, 34]] and place.tolist() == [[300, 5]]
    assert rot.tolist() == [1]  # bin k of 8 stands for -k * 45 degrees (the reference's convention)
    assert agent.place.bin_yaw(1) == pytest.approx(-math.radians(45))
    pose1[0, 3:] = yaw_to_quat(1.0 + math.radians(90))
    assert agent.action_targets(pose0, pose1, (320, 160))[2].tolist() == [6]


@pytest.mark.parametrize("batch_size", [1, 3])
def test_transporter_loss_any_batch_size(batch_size: int, tiny_config) -> None:
    agent = make_agent("transporter_only", tiny_config("transporter_only"))
    target = (RED_BLOCK, GREEN_BOWL, 2, "")
    loss, info = agent.compute_loss(_batch([target] * batch_size))
    assert loss.shape == () and math.isfinite(loss.item())
    assert set(info) == {"loss", "pick_loss", "place_loss"}
    # Untrained, both terms are close to the uniform cross-entropy.
    assert abs(info["pick_loss"] - math.log(H * W)) < 1.0
    assert abs(info["place_loss"] - math.log(8 * H * W)) < 1.0


def test_act_outputs(two_stream: PickPlaceAgent) -> None:
    out = two_stream.act(_scene(), "put the red block in the green bowl")
    for key in ("pick_heatmap", "place_heatmap"):
        assert out[key].shape == (H, W) and out[key].dtype == np.float32
    assert abs(out["pick_heatmap"].sum() - 1.0) < 1e-4
    assert out["place_heatmap"].max() <= 1.0
    (x, y, z), quat = out["pose0"]
    assert len(quat) == 4 and 0.25 <= x <= 0.75 and -0.5 <= y <= 0.5
    with pytest.raises(ValueError):
        two_stream.act(_scene(), None)


def test_transporter_fits_pick_and_place(tiny_config) -> None:
    torch.manual_seed(0)
    agent = make_agent("transporter_only", tiny_config("transporter_only", lr=1e-3))
    assert _fit(agent, [(RED_BLOCK, GREEN_BOWL, 3, "")], max_steps=120, check_every=10) is not None


def test_half_size_map_fits_within_a_pixel_and_round_trips(tmp_path: Path, tiny_config) -> None:
    """map_scale 0.5: the nets see a map half the size, the heatmaps keep the input's; still learns a target."""
    torch.manual_seed(0)
    agent = make_agent("transporter_only", tiny_config("transporter_only", lr=1e-3, map_scale=0.5))
    assert agent.place.crop_size == 16
    assert _fit(agent, [(RED_BLOCK, GREEN_BOWL, 3, "")], max_steps=400, check_every=10, hits=_within_a_pixel)
    out = agent.act(_scene())
    assert out["pick_heatmap"].shape == out["place_heatmap"].shape == (H, W)
    agent.save_checkpoint(tmp_path / "agent.pt")
    loaded = PickPlaceAgent.from_pretrained(tmp_path / "agent.pt")
    assert loaded.config.map_scale == 0.5 and loaded.place.crop_size == 16
    _assert_same_act(agent, loaded, None)


@pytest.mark.parametrize("scale", [0.0, 1.5, 0.25])
def test_map_scale_outside_its_range_is_refused(scale: float) -> None:
    with pytest.raises(ConfigError, match="map_scale"):
        make_agent("transporter_only", {"map_scale": scale})


@pytest.mark.e2e
def test_clip_only_fits_pick_and_place(tiny_config) -> None:
    """The semantic stream alone (random CLIP, RGB only) learns where to pick and place, with the rotation.

    Width 0.25: at 0.125 its last decoder stages are 2-4 channels wide, their ReLUs can all be dead at
    init, and the query net's output is then the same for every rotation (place loss stuck at log 8).
    """
    torch.manual_seed(0)
    agent = make_agent("clip_only", tiny_config("clip_only", lr=3e-4, width=0.25))
    target = (RED_BLOCK, GREEN_BOWL, 3, "put the red block in the green bowl")
    assert _fit(agent, [target], max_steps=80, check_every=10) is not None


def test_two_stream_frozen_clip_is_unchanged_by_training(two_stream: PickPlaceAgent) -> None:
    clip = two_stream.encoder
    assert clip is not None
    before = {k: v.clone() for k, v in clip.state_dict().items()}
    batch = _batch([(RED_BLOCK, GREEN_BOWL, 3, "put the red block in the green bowl")])
    optimizer = two_stream.make_optimizer()
    assert not any(p.requires_grad for p in clip.parameters())
    assert all(p.requires_grad for p in two_stream.trainable_parameters())
    two_stream.train()
    losses = [optimizer_step(two_stream.compute_loss, batch, optimizer)["loss"] for _ in range(4)]
    assert losses[-1] < losses[0]
    assert not clip.training and not any(m.training for m in clip.modules())
    after = clip.state_dict()
    assert all(torch.equal(before[k], after[k]) for k in before)  # weights and BN running stats
    # One CLIP instance is shared by the pick, key and query nets.
    assert two_stream.pick.net.encoder is clip
    assert two_stream.place.key_net.encoder is clip and two_stream.place.query_net.encoder is clip


def _assert_same_act(a: PickPlaceAgent, b: PickPlaceAgent, instruction: str | None) -> None:
    out_a, out_b = a.act(_scene(), instruction), b.act(_scene(), instruction)
    for key in out_a:
        if isinstance(out_a[key], np.ndarray):
            np.testing.assert_array_equal(out_a[key], out_b[key])
        else:
            assert out_a[key] == out_b[key], key


@pytest.mark.parametrize("name", ["transporter_only", "two_stream"])
def test_checkpoint_round_trip(name: str, tmp_path: Path, tiny_config) -> None:
    torch.manual_seed(1)
    agent = make_agent(name, tiny_config(name))
    agent.train()
    batch = _batch([(RED_BLOCK, GREEN_BOWL, 3, "put the red block in the green bowl")])
    optimizer_step(agent.compute_loss, batch, agent.make_optimizer())
    path = tmp_path / "ckpt" / "agent.pt"
    agent.save_checkpoint(path)
    assert [p.name for p in path.parent.iterdir()] == ["agent.pt"]  # no temp file left behind
    payload = torch.load(path, weights_only=True)
    assert payload["agent"] == name
    assert payload["config"] == agent.config.to_dict()
    assert payload["clip_weights"] == ("random" if name == "two_stream" else None)
    assert not any("clip" in k for k in payload["state_dict"])
    params = dict(agent.named_parameters())
    saved_params = [v for k, v in payload["state_dict"].items() if k in params]
    assert sum(v.numel() for v in saved_params) == sum(p.numel() for p in agent.trainable_parameters())
    # Besides the weights only the U-Net batch norms' statistics (two_stream), never a frozen tensor.
    others = {k.rsplit(".", 1)[-1] for k in payload["state_dict"] if k not in params}
    assert others <= {"running_mean", "running_var", "num_batches_tracked"}
    torch.manual_seed(2)
    loaded = PickPlaceAgent.from_pretrained(path)
    assert type(loaded) is type(agent)
    _assert_same_act(agent, loaded, "put the red block in the green bowl")


def test_checkpoints_of_the_pre_parity_networks_are_refused_in_one_line(tmp_path: Path, tiny_config) -> None:
    from cliport.errors import CheckpointError

    payload = make_agent("transporter_only", tiny_config("transporter_only")).checkpoint_payload()
    assert payload["format"] == 2 and payload["cliport_version"]
    for fmt, phrase in ((1, "before 0.2.0 (checkpoint format 1)"), (3, "newer cliport (checkpoint format 3)")):
        path = tmp_path / f"format{fmt}.pt"
        torch.save({**payload, "format": fmt}, path)
        with pytest.raises(CheckpointError, match=re.escape(phrase)) as err:
            PickPlaceAgent.from_pretrained(path)
        assert str(path) in str(err.value) and "\n" not in str(err.value)
    old = {k: v for k, v in payload.items() if k not in ("format", "cliport_version")}  # before formats existed
    torch.save(old, tmp_path / "old.pt")
    with pytest.raises(CheckpointError, match="retrain"):
        PickPlaceAgent.from_pretrained(tmp_path / "old.pt")


@pytest.mark.slow
def test_checkpoint_loads_in_a_fresh_process(tmp_path: Path, tiny_config) -> None:
    torch.manual_seed(3)
    agent = make_agent("two_stream", tiny_config("two_stream"))
    path = tmp_path / "agent.pt"
    agent.save_checkpoint(path)
    expected = agent.act(_scene(), "pack the box")["place_heatmap"]
    np.save(tmp_path / "obs_color.npy", _scene()["color"])
    np.save(tmp_path / "obs_height.npy", _scene()["height"])
    script = (
        "import numpy as np, sys\n"
        "from cliport.agents import PickPlaceAgent\n"
        "d = sys.argv[1]\n"
        "obs = {'color': np.load(d + '/obs_color.npy'), 'height': np.load(d + '/obs_height.npy')}\n"
        "agent = PickPlaceAgent.from_pretrained(d + '/agent.pt')\n"
        "np.save(d + '/got.npy', agent.act(obs, 'pack the box')['place_heatmap'])\n"
    )
    subprocess.run([sys.executable, "-c", script, str(tmp_path)], check=True, timeout=300)
    np.testing.assert_array_equal(np.load(tmp_path / "got.npy"), expected)


@pytest.mark.slow
def test_two_stream_learns_two_instructions_on_one_image(tiny_config) -> None:
    torch.manual_seed(0)
    agent = make_agent("two_stream", tiny_config("two_stream", lr=5e-4))
    targets = [
        (RED_BLOCK, GREEN_BOWL, 3, "put the red block in the green bowl"),
        (BLUE_BLOCK, YELLOW_BOWL, 6, "put the blue block in the yellow bowl"),
    ]
    assert _fit(agent, targets, max_steps=400, check_every=10) is not None


@pytest.mark.parametrize("name", ["transporter_only", "two_stream"])
@pytest.mark.e2e
@pytest.mark.paper_size
def test_real_size_forward(name: str) -> None:
    cfg = {"clip_weights": "random"} if name == "two_stream" else {}
    agent = make_agent(name, cfg)
    rng = np.random.default_rng(0)
    obs = {
        "color": rng.integers(0, 255, (320, 160, 3), dtype=np.uint8),
        "height": rng.uniform(0, 0.05, (320, 160)).astype(np.float32),
    }
    out = agent.act(obs, "put the red block in the green bowl")
    assert out["pick_heatmap"].shape == (320, 160) and out["place_heatmap"].shape == (320, 160)
    assert 0 <= out["place_rot"] < 2 * math.pi


# two_stream's similarity_maps: CLIP's dense image-text similarity to the instruction and its phrases joins the
# semantic decoder's laterals; off, the net is the reference's.

SIMILARITY_INSTRUCTION = "put the red block in the green bowl"


def _similarity_config(tiny_config, **overrides: object) -> dict[str, object]:
    return tiny_config("two_stream", semantic_encoder="cliport-RN-tiny", **overrides)


def test_phrases_run_from_an_article_to_a_preposition() -> None:
    assert instruction_phrases("put the pink block in the red bowl") == ["the pink block", "the red bowl"]
    assert instruction_phrases("Pack the hammer, then the blue box.") == ["the hammer", "the blue box"]
    assert instruction_phrases("put a white block on the brown block", n=1) == ["a white block"]
    assert instruction_phrases("done placing blocks") == []


def test_similarity_maps_widen_only_the_laterals_and_the_sentence(tiny_config) -> None:
    torch.manual_seed(0)
    plain = make_agent("two_stream", _similarity_config(tiny_config))
    torch.manual_seed(0)
    maps = make_agent("two_stream", _similarity_config(tiny_config, similarity_maps=True))
    plain_state, maps_state = plain.state_dict(), maps.state_dict()
    assert plain_state.keys() == maps_state.keys()
    widened = {k for k in plain_state if plain_state[k].shape != maps_state[k].shape}
    assert widened and all(".semantic.fusions." in k for k in widened)
    for k in widened:  # the 1x1 lateral fusion convs read SIMILARITY_MAPS more channels
        assert maps_state[k].shape[1] == plain_state[k].shape[1] + SIMILARITY_MAPS
    dim = maps.encoder.sentence_dim
    assert plain.sentence_features([SIMILARITY_INSTRUCTION]).shape == (1, dim)
    features = maps.sentence_features([SIMILARITY_INSTRUCTION])
    assert features.shape == (1, (1 + SIMILARITY_MAPS) * dim)
    texts = features[0, dim:].view(SIMILARITY_MAPS, dim)
    torch.testing.assert_close(texts.norm(dim=1), torch.ones(SIMILARITY_MAPS))
    torch.testing.assert_close(features[0, :dim], plain.sentence_features([SIMILARITY_INSTRUCTION])[0])


def test_similarity_maps_carry_the_phrases_into_the_pick(tiny_config) -> None:
    """The same gate feature with other phrase embeddings gives another pick map: the maps are read."""
    torch.manual_seed(0)
    agent = make_agent("two_stream", _similarity_config(tiny_config, similarity_maps=True))
    inputs = agent.training_inputs(_batch([(RED_BLOCK, GREEN_BOWL, 3, SIMILARITY_INSTRUCTION)]))
    sentence = agent.sentence_features([SIMILARITY_INSTRUCTION])
    other = agent.sentence_features(["put the blue block in the yellow bowl"])
    swapped = torch.cat([sentence[:, : agent.encoder.sentence_dim], other[:, agent.encoder.sentence_dim :]], dim=1)
    raw = raw_input(inputs["color"], inputs["height"])
    with torch.no_grad():
        own, moved = agent.pick.net(raw, sentence), agent.pick.net(raw, swapped)
    assert not torch.allclose(own, moved)
    with pytest.raises(ValueError, match="reads 1024 sentence channels"):
        agent.pick.net(raw, sentence[:, : agent.encoder.sentence_dim])


def _train_and_save(agent, tmp_path: Path) -> Path:
    """Four steps on one sample (the loss must fall), then the checkpoint's path."""
    batch = _batch([(RED_BLOCK, GREEN_BOWL, 3, SIMILARITY_INSTRUCTION)])
    optimizer = agent.make_optimizer()
    agent.train()
    losses = [optimizer_step(agent.compute_loss, batch, optimizer)["loss"] for _ in range(4)]
    assert losses[-1] < losses[0]
    path = tmp_path / "agent.pt"
    agent.save_checkpoint(path)
    return path


def test_similarity_maps_train_and_round_trip(tiny_config, tmp_path: Path) -> None:
    torch.manual_seed(0)
    agent = make_agent("two_stream", _similarity_config(tiny_config, similarity_maps=True, lr=5e-4))
    path = _train_and_save(agent, tmp_path)
    assert torch.load(path, weights_only=True)["config"]["similarity_maps"] is True
    loaded = PickPlaceAgent.from_pretrained(path)
    assert loaded.config.similarity_maps and loaded.config.similarity_scale == agent.config.similarity_scale
    _assert_same_act(agent, loaded, SIMILARITY_INSTRUCTION)


def test_similarity_scale_reads_the_trunk_on_a_resized_image(tiny_config) -> None:
    """At scale 2 the maps' grid doubles per side; at scale 1 they are the trunk's own last level's."""
    torch.manual_seed(0)
    agent = make_agent("two_stream", _similarity_config(tiny_config, similarity_maps=True, similarity_scale=1.0))
    net = agent.pick.net
    images = torch.rand(1, 6, 64, 96)
    layer4 = net.encoder_features(images)[-1]
    assert layer4.shape[-2:] == (2, 3)
    torch.testing.assert_close(net.dense_embeddings(images, layer4), net.encoder.dense_embeddings(layer4))
    net.similarity_scale = 2.0
    assert net.dense_embeddings(images, layer4).shape == (1, net.encoder.sentence_dim, 4, 6)
    with pytest.raises(ConfigError, match="similarity_scale must be positive, got 0"):
        make_agent("two_stream", _similarity_config(tiny_config, similarity_maps=True, similarity_scale=0))


def test_without_language_gates_the_instruction_enters_through_the_maps_alone(tiny_config) -> None:
    torch.manual_seed(0)
    agent = make_agent("two_stream", _similarity_config(tiny_config, similarity_maps=True, language_gates=False))
    inputs = agent.training_inputs(_batch([(RED_BLOCK, GREEN_BOWL, 3, SIMILARITY_INSTRUCTION)]))
    raw = raw_input(inputs["color"], inputs["height"])
    dim = agent.encoder.sentence_dim
    sentence = agent.sentence_features([SIMILARITY_INSTRUCTION])
    other = agent.sentence_features(["put the blue block in the yellow bowl"])
    other_gate = torch.cat([other[:, :dim], sentence[:, dim:]], dim=1)
    other_maps = torch.cat([sentence[:, :dim], other[:, dim:]], dim=1)
    with torch.no_grad():
        own = agent.pick.net(raw, sentence)
        torch.testing.assert_close(agent.pick.net(raw, other_gate), own)  # the gates read no sentence
        assert not torch.allclose(agent.pick.net(raw, other_maps), own)  # the maps do
    with pytest.raises(ConfigError, match="language_gates = false needs similarity_maps"):
        make_agent("two_stream", _similarity_config(tiny_config, language_gates=False))


def test_a_phrase_bank_turns_the_maps_into_probabilities_and_rides_in_the_checkpoint(tiny_config, tmp_path) -> None:
    torch.manual_seed(0)
    config = _similarity_config(tiny_config, similarity_maps=True, similarity_bank=True, lr=5e-4)
    agent = make_agent("two_stream", config)
    assert agent.phrase_bank is agent.pick.net.bank is agent.place.query_net.bank
    with pytest.raises(RuntimeError, match="phrase bank that was never fitted"):
        agent.sentence_features([SIMILARITY_INSTRUCTION])
    agent.phrase_bank.fit(agent.encoder, [SIMILARITY_INSTRUCTION, "put the blue block in the yellow bowl"])
    rng = np.random.default_rng(0)
    obs = {"color": rng.integers(0, 255, (320, 160, 3), dtype=np.uint8), "height": np.zeros((320, 160), np.float32)}
    maps = agent.similarity_heatmaps(obs, "put the pink block in the red bowl")
    for values in maps.values():
        assert values.min() >= 0 and values.max() <= 1  # probabilities, not cosines
    path = _train_and_save(agent, tmp_path)
    loaded = PickPlaceAgent.from_pretrained(path)
    assert loaded.phrase_bank.fitted and loaded.config.similarity_bank
    torch.testing.assert_close(loaded.phrase_bank.embeddings, agent.phrase_bank.embeddings)
    _assert_same_act(agent, loaded, SIMILARITY_INSTRUCTION)
    with pytest.raises(ConfigError, match="similarity_bank = true needs similarity_maps"):
        make_agent("two_stream", _similarity_config(tiny_config, similarity_bank=True))


def test_similarity_heatmaps_show_what_the_pick_net_reads(tiny_config) -> None:
    """One map per text at the observation's size; agents without maps have none."""
    torch.manual_seed(0)
    agent = make_agent("two_stream", _similarity_config(tiny_config, similarity_maps=True, map_scale=0.5))
    rng = np.random.default_rng(0)
    obs = {"color": rng.integers(0, 255, (320, 160, 3), dtype=np.uint8), "height": np.zeros((320, 160), np.float32)}
    maps = agent.similarity_heatmaps(obs, SIMILARITY_INSTRUCTION)
    assert list(maps) == [SIMILARITY_INSTRUCTION, "the red block", "the green bowl"]
    for values in maps.values():
        assert values.shape == (320, 160) and values.dtype == np.float32
        assert np.all(np.abs(values) <= 1 + 1e-5) and values.std() > 0
    assert not np.allclose(maps["the red block"], maps["the green bowl"])
    assert make_agent("two_stream", _similarity_config(tiny_config)).similarity_heatmaps(obs, "x") == {}


def test_clip_only_refuses_similarity_maps(tiny_config) -> None:
    with pytest.raises(ConfigError, match="similarity_maps is an option of the two_stream agent"):
        make_agent("clip_only", tiny_config("clip_only", semantic_encoder="cliport-RN-tiny", similarity_maps=True))
