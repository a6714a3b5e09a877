"""Image-only work once per distinct image: a batch that repeats an image (a contrasting pair, a scene under several
instructions) computes what it computed per sample, to float rounding, with the image-only layers run fewer times."""

from __future__ import annotations

import pytest
import torch

from cliport.agents import make_agent
from cliport.models import distinct_images as distinct
from cliport.models.blocks import UpBlock
from cliport.models.preprocess import raw_input


def _assert_close_to_scale(got: list[torch.Tensor], want: list[torch.Tensor], rel: float) -> None:
    """Equal to ``rel`` of the largest magnitude among ``want``: sums of the same products in another order (a
    gradient that is zero in exact arithmetic, such as a conv bias before a batch norm, is rounding either way)."""
    scale = max(w.abs().max().item() for w in want)
    assert len(got) == len(want) > 0
    for g, w in zip(got, want, strict=True):
        torch.testing.assert_close(g, w, rtol=0, atol=rel * scale)


def test_distinct_images_index_each_sample_in_order_of_first_appearance() -> None:
    a, b, c = torch.rand(3, 2, 4, 4)
    found = distinct.distinct_images(torch.stack([a, b, a, c, b]))
    assert found is not None
    assert found.index.tolist() == [0, 1, 0, 2, 1]
    assert torch.equal(found.images, torch.stack([a, b, c]))
    assert torch.equal(distinct.per_sample(found.images, found.index), torch.stack([a, b, a, c, b]))


def test_no_distinct_images_where_every_image_differs_or_there_is_one() -> None:
    assert distinct.distinct_images(torch.rand(3, 2, 4, 4)) is None
    assert distinct.distinct_images(torch.rand(1, 2, 4, 4)) is None
    nearly = torch.rand(1, 2, 4, 4).repeat(2, 1, 1, 1)
    nearly[1, 0, 0, 0] += 1e-6  # one value apart is another image
    assert distinct.distinct_images(nearly) is None


def test_no_distinct_images_on_devices_not_listed(monkeypatch) -> None:
    monkeypatch.setattr(distinct, "DISTINCT_DEVICES", set())
    assert distinct.distinct_images(torch.rand(1, 2, 4, 4).repeat(2, 1, 1, 1)) is None


def test_up_block_over_distinct_skips_trains_as_over_the_per_sample_skips() -> None:
    torch.manual_seed(0)
    up = UpBlock(40 + 8, 6)
    skips = torch.randn(2, 40, 9, 10)
    index = torch.tensor([0, 1, 0])
    x = torch.randn(3, 8, 4, 5, requires_grad=True)
    target = torch.randn(3, 6, 9, 10)

    def gradients(shared: bool) -> tuple[torch.Tensor, list[torch.Tensor]]:
        up.zero_grad(set_to_none=True)
        x.grad = None
        out = up(x, skips, index) if shared else up(x, skips[index])
        (out * target).sum().backward()
        return out.detach(), [x.grad.clone(), *(p.grad.clone() for p in up.parameters())]

    out, grads = gradients(shared=True)
    plain_out, plain_grads = gradients(shared=False)
    _assert_close_to_scale([out], [plain_out], 1e-6)
    _assert_close_to_scale(grads, plain_grads, 1e-6)
    with torch.no_grad():  # acting: the same values without autograd
        _assert_close_to_scale([up(x, skips, index)], [plain_out], 1e-6)


def _pair_batch() -> dict:
    """One image under two instructions, picking and placing at other pixels: a contrasting pair."""
    g = torch.Generator().manual_seed(1)
    color = torch.randint(0, 255, (1, 64, 32, 3), dtype=torch.uint8, generator=g).expand(2, -1, -1, -1)
    height = (torch.rand(1, 64, 32, generator=g) * 0.05).expand(2, -1, -1)
    return {
        "color": color.contiguous(),
        "height": height.contiguous(),
        "pick_pix": torch.tensor([[20, 10], [40, 20]]),
        "place_pix": torch.tensor([[30, 12], [10, 25]]),
        "place_rot": torch.tensor([1, 3]),
        "lang": ["put the red block in the green bowl", "put the blue block in the brown bowl"],
    }


@pytest.mark.parametrize("name", ["two_stream", "clip_only"])
def test_a_pair_trains_as_its_samples_computed_apart(name: str, tiny_config, monkeypatch) -> None:
    """The pick and key nets see the pair's image once (spatial stream, trunk, the decoder's image-only layers);
    their maps and every gradient equal those of the per-sample computation to float rounding."""
    torch.manual_seed(0)
    agent = make_agent(name, tiny_config(name, n_rotations=4, semantic_encoder="cliport-RN-tiny"))
    agent.train()
    batch = _pair_batch()
    seen: list[int] = []  # the batch sizes of the pick and key nets' decoder bottlenecks (image-only layers)
    for net in (agent.pick.net, agent.place.key_net):
        net.semantic.bottleneck.register_forward_pre_hook(lambda _, inputs: seen.append(inputs[0].shape[0]))
    encoder = agent.encoder

    def run() -> tuple[list[torch.Tensor], list[torch.Tensor]]:
        agent.zero_grad(set_to_none=True)
        encoder.forget_images()
        inputs = agent.training_inputs(batch)
        x = raw_input(inputs["color"], inputs["height"])
        maps = [agent.pick(x, inputs["sentence"]), agent.place(x, inputs["pick_pix"], inputs["sentence"])]
        total, _ = agent._loss_terms(**inputs)
        total.backward()
        grads = [p.grad.clone() for p in agent.parameters() if p.grad is not None]
        return [m.detach() for m in maps], grads

    maps, grads = run()
    shared_batches = list(seen)
    seen.clear()
    monkeypatch.setattr(distinct, "DISTINCT_DEVICES", set())
    plain_maps, plain_grads = run()
    for got, want in zip(maps, plain_maps, strict=True):
        _assert_close_to_scale([got], [want], 1e-5)
    _assert_close_to_scale(grads, plain_grads, 1e-4)  # the parity tests' bound for a training step's gradients
    # Shared: the pair's image once in the pick and key nets; apart: twice.
    assert shared_batches == [1, 1, 1, 1] and seen == [2, 2, 2, 2]


def test_no_sharing_while_the_trunks_norms_train(tiny_config) -> None:
    """The cliport recipe's trunk batch norms update their statistics once per sample, as reference steps do."""
    agent = make_agent(
        "two_stream", tiny_config("two_stream", per_net_clip_stats=True, semantic_encoder="cliport-RN-tiny")
    )
    net = agent.pick.net
    pair = torch.rand(1, 6, 32, 32).repeat(2, 1, 1, 1)
    net.train()
    assert net.distinct_inputs(pair) is not None
    assert net.set_encoder_norm_training(True)
    assert net.distinct_inputs(pair) is None
    net.eval()
    assert net.distinct_inputs(pair) is not None
