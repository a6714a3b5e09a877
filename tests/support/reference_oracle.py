"""Runs the reference CLIPort code (github.com/cliport/cliport, outside this project) as a test oracle.

Never imported by the project or the tests: they run it as a subprocess (the reference's package is also
called ``cliport``) with the reference folder given by ``--reference-dir`` (the folder described in its own
README, e.g. ``../shared/reference-cliport``). Inputs and outputs are ``torch.save`` files of tensors,
strings and numbers only.

    python tests/support/reference_oracle.py --reference-dir R weights AGENT OUT.ckpt [--seed S] [--perturb-clip-bn]
                                                               [--act REQUEST ACT_OUT [--clip-fp16]]
        Builds the reference agent with seeded random weights, re-initialises its trainable weights so
        its heatmaps are not flat (see ``_rescale``), calibrates its CLIP's batch-norm statistics (and
        with --perturb-clip-bn gives each net's CLIP copy its own statistics, as the reference's training
        leaves them), and saves a Lightning-style checkpoint dict (``state_dict`` and Lightning's
        bookkeeping) and, beside it, OUT.clip.pt: the CLIP state dict (OpenAI's keys) of the pick net.
        With --act, then runs ``act`` (below) with the agent it holds, whose state is the checkpoint's, in
        the same process (building a paper-size reference agent takes 10-25 s on a CPU).
    python tests/support/reference_oracle.py --reference-dir R act AGENT CKPT REQUEST OUT [--clip-fp16]
        Builds the agent, loads the checkpoint's state dict and runs the reference's own act() on each
        observation of REQUEST ({"images": [(H, W, 6) float32, colour 0..255 and height x3], "lang":
        [str]}), recording the pick and place logits (the softmax inputs), the key and query outputs and
        act()'s result. The reference converts CLIP to fp16 (its build_model does); without --clip-fp16
        every CLIP copy is put back to fp32 after loading, so the nets are compared in fp32.
    python tests/support/reference_oracle.py --reference-dir R train AGENT OUT.ckpt REQUEST TRAINED_OUT [--seed S]
                                                           [--perturb-clip-bn] [--n-rotations N] [--steps K]
        As ``weights`` (the checkpoint OUT.ckpt and OUT.ckpt.clip.pt hold the state before training), then
        puts every CLIP copy back to fp32 and runs K passes (default 1) of the reference's own training step
        over REQUEST's frames ({"frames": [{"img": (H, W, 6) float32, "p0": (2,), "p1": (2,) int pixels,
        "p1_theta": float, "lang": str}]}): ``attention.train(); transport.train(); attn_training_step(frame);
        transport_training_step(frame)``, what its ``training_step`` runs minus Lightning's bookkeeping.
        TRAINED_OUT gets {"state_dict": the agent's state after the steps, "losses": [(pick, place), ...],
        "first_grads": {parameter name: the gradient its optimiser stepped with first (the first frame's)},
        "optimizers": {"attn" / "trans": the optimiser's settings (lr, betas, eps, ...)}}.
        ``--n-rotations`` builds the agents with another rotation count than the reference's 36.
    python tests/support/reference_oracle.py --reference-dir R clip CKPT REQUEST OUT
        The pick net's CLIP (fp32): token ids, sentence features and the prepool trunk levels of REQUEST's
        "texts" and "rgb" ((N, 3, H, W) float in [0, 1]).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import types
from typing import Any


def _import_reference(folder: str) -> types.ModuleType:
    folder = os.path.abspath(folder)
    sys.path.insert(0, folder)
    import build_reference

    return build_reference


def _clip_copies(agent: Any) -> list[tuple[str, Any]]:
    return [(name, m) for name, m in agent.named_modules() if name.endswith("clip_rn50")]


def _rescale(agent: Any, seed: int) -> None:
    """LeCun-normal weights (std 1 / sqrt(fan_in)) for every trainable conv and linear layer, small random
    biases and batch-norm affines: the default initialisation gives logits that span ~1e-3, which would
    hide differences of the functions computed."""
    import torch
    from torch import nn

    gen = torch.Generator().manual_seed(seed)
    for name, module in agent.named_modules():
        if "clip_rn50" in name or "text_encoder" in name:
            continue
        with torch.no_grad():
            if isinstance(module, (nn.Conv2d, nn.Linear)):
                fan_in = module.weight[0].numel()
                module.weight.copy_(torch.randn(module.weight.shape, generator=gen) / math.sqrt(fan_in))
                if module.bias is not None:
                    module.bias.copy_(torch.randn(module.bias.shape, generator=gen) * 0.1)
            elif isinstance(module, nn.BatchNorm2d):
                module.weight.copy_(1 + 0.1 * torch.randn(module.weight.shape, generator=gen))
                module.bias.copy_(0.1 * torch.randn(module.bias.shape, generator=gen))


def _calibrate_clip(clip: Any, seed: int, scale: float) -> None:
    """Batch-norm statistics of a random CLIP trunk from seeded noise images (left at mean 0 / var 1 its
    features shrink a thousandfold by layer4); ``scale`` perturbs them per copy."""
    import torch
    from torch import nn

    visual = clip.visual
    dtype = visual.conv1.weight.dtype
    visual.float()
    norms = [m for m in visual.modules() if isinstance(m, nn.BatchNorm2d)]
    for norm in norms:
        norm.reset_running_stats()
        norm.momentum = None
    gen = torch.Generator().manual_seed(seed)
    visual.train()
    with torch.no_grad():
        visual.prepool_im(torch.randn(4, 3, 96, 96, generator=gen))
    visual.eval()
    for norm in norms:
        norm.momentum = 0.1
        with torch.no_grad():
            norm.running_mean.mul_(scale)
            norm.running_var.mul_(scale)
    visual.to(dtype)
    for norm in norms:  # the reference keeps its batch norms in fp32 (convert_weights skips them)
        norm.float()


def cmd_weights(ref: types.ModuleType, args: argparse.Namespace) -> Any:
    import torch

    if args.n_rotations != 36:
        base_config = ref.config

        def config(agent_name: str, task: str = "packing-boxes-pairs-seen-colors") -> dict:
            cfg = base_config(agent_name, task)
            cfg["train"]["n_rotations"] = args.n_rotations
            return cfg

        ref.config = config
    with contextlib.redirect_stdout(sys.stderr):
        agent = ref.build(args.agent, seed=args.seed)
    _rescale(agent, args.seed + 1)
    copies = _clip_copies(agent)
    for i, (_, clip) in enumerate(copies):
        _calibrate_clip(clip, seed=args.seed + 2, scale=1.0 + 0.25 * i if args.perturb_clip_bn else 1.0)
    state = {k: v.detach().clone() for k, v in agent.state_dict().items()}
    ckpt = {
        "epoch": 0,
        "global_step": 1000,
        "pytorch-lightning_version": "1.0.3",
        "state_dict": state,
        "optimizer_states": [],
        "lr_schedulers": [],
        "callbacks": {},
        "hyper_parameters": {"cfg": ref.config(args.agent)},
    }
    torch.save(ckpt, args.out)
    if copies:
        clip_sd = {k: v.detach().float().clone() for k, v in copies[0][1].state_dict().items()}
        torch.save(clip_sd, args.out + ".clip.pt")
    if getattr(args, "act", None):
        if not args.clip_fp16:
            for _, clip in copies:
                clip.float()
        _act(agent, args.act[0], args.act[1])
    return agent


def cmd_train(ref: types.ModuleType, args: argparse.Namespace) -> None:
    import torch

    agent = cmd_weights(ref, args)
    for _, clip in _clip_copies(agent):
        clip.float()
    frames = torch.load(args.request, weights_only=True)["frames"]
    losses = []
    # The gradients each optimiser steps with on its first call (the first frame's, before any update), read by
    # a step pre-hook: the released training steps are run as they are.
    names = {id(p): name for name, p in agent.named_parameters()}
    first_grads: dict[str, Any] = {}

    def record(optimizer: Any, *_: Any) -> None:
        params = [p for group in optimizer.param_groups for p in group["params"] if p.grad is not None]
        if not any(names[id(p)] in first_grads for p in params):
            first_grads.update({names[id(p)]: p.grad.detach().clone() for p in params})

    optimizers = agent._optimizers
    for optimizer in optimizers.values():
        optimizer.register_step_pre_hook(record)
    settings = {
        key: {k: v for k, v in opt.defaults.items() if isinstance(v, (bool, int, float, tuple)) or v is None}
        for key, opt in optimizers.items()
    }
    for _ in range(args.steps):
        for frame in frames:
            sample = {
                "img": frame["img"].numpy(),
                "p0": tuple(int(x) for x in frame["p0"]),
                "p0_theta": 0.0,
                "p1": tuple(int(x) for x in frame["p1"]),
                "p1_theta": float(frame["p1_theta"]),
                "lang_goal": frame["lang"],
            }
            agent.attention.train()
            agent.transport.train()
            pick_loss, _ = agent.attn_training_step(sample)
            place_loss, _ = agent.transport_training_step(sample)
            losses.append((float(pick_loss), float(place_loss)))
    state = {k: v.detach().clone() for k, v in agent.state_dict().items()}
    torch.save(
        {"state_dict": state, "losses": losses, "first_grads": first_grads, "optimizers": settings}, args.trained_out
    )


def _build_loaded(ref: types.ModuleType, agent_name: str, ckpt_path: str, clip_fp16: bool) -> Any:
    import torch

    with contextlib.redirect_stdout(sys.stderr):
        agent = ref.build(agent_name, seed=0)
    state = torch.load(ckpt_path, map_location="cpu", weights_only=False)["state_dict"]
    agent.load_state_dict(state)
    if not clip_fp16:
        for _, clip in _clip_copies(agent):
            clip.float()
    return agent


class _RecordingFunctional(types.ModuleType):
    """Stands in for torch.nn.functional in the reference's modules: records every softmax input."""

    def __init__(self, records: list) -> None:
        super().__init__("recording_functional")
        self._records = records

    def __getattr__(self, name: str) -> Any:
        import torch.nn.functional

        return getattr(torch.nn.functional, name)

    def softmax(self, x: Any, dim: int) -> Any:
        import torch.nn.functional

        self._records.append(x.detach().clone())
        return torch.nn.functional.softmax(x, dim=dim)


def cmd_act(ref: types.ModuleType, args: argparse.Namespace) -> None:
    _act(_build_loaded(ref, args.agent, args.ckpt, args.clip_fp16), args.request, args.out)


def _act(agent: Any, request_path: str, out: str) -> None:
    import numpy as np
    import torch
    import torch.nn.functional

    request = torch.load(request_path, weights_only=True)
    softmax_inputs: list = []
    recorder = _RecordingFunctional(softmax_inputs)
    for name, module in list(sys.modules.items()):
        if name.startswith("cliport.") and getattr(module, "F", None) is torch.nn.functional:
            module.F = recorder
    transport_outputs: list = []
    transport = agent.transport.transport

    def recording_transport(*a: Any) -> Any:
        logits, kernel = transport(*a)
        transport_outputs.append((logits.detach().clone(), kernel.detach().clone()))
        return logits, kernel

    agent.transport.transport = recording_transport
    results = []
    for img, lang in zip(request["images"], request["lang"], strict=True):
        img = img.numpy().astype(np.float32)
        agent.test_ds = types.SimpleNamespace(get_image=lambda obs, img=img: img)
        softmax_inputs.clear()
        transport_outputs.clear()
        with torch.no_grad():
            act = agent.act({}, {"lang_goal": lang})
        h, w = img.shape[:2]
        pick_logits, place_logits = softmax_inputs
        key, query = transport_outputs[0]
        results.append(
            {
                "pick_logits": pick_logits.reshape(h, w),
                "place_logits": place_logits.reshape(-1, h, w),
                "key": key,
                "query": query,
                "pose0": [torch.as_tensor(np.asarray(x, dtype=np.float64)) for x in act["pose0"]],
                "pose1": [torch.as_tensor(np.asarray(x, dtype=np.float64)) for x in act["pose1"]],
                "pick": torch.tensor([float(x) for x in act["pick"]], dtype=torch.float64),
                "place": torch.tensor([float(x) for x in act["place"]], dtype=torch.float64),
            }
        )
    torch.save(results, out)


def cmd_clip(ref: types.ModuleType, args: argparse.Namespace) -> None:
    import torch

    from cliport.models.core.clip import tokenize

    agent = _build_loaded(ref, args.agent, args.ckpt, clip_fp16=False)
    clip = _clip_copies(agent)[0][1]
    request = torch.load(args.request, weights_only=True)
    mean = torch.tensor([0.48145466, 0.4578275, 0.40821073]).view(1, 3, 1, 1)
    std = torch.tensor([0.26862954, 0.26130258, 0.27577711]).view(1, 3, 1, 1)
    with torch.no_grad():
        _, levels = clip.visual.prepool_im((request["rgb"] - mean) / std)
        tokens = torch.cat([tokenize([t]) for t in request["texts"]])
        sentences = torch.cat([clip.encode_text_with_embeddings(tokenize([t]))[0] for t in request["texts"]])
    # prepool_im's list: the stem's three convs, its average pool, then layer1..4.
    torch.save({"tokens": tokens, "sentences": sentences.float(), "levels": [x.float() for x in levels[-5:]]}, args.out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference-dir", required=True)
    sub = parser.add_subparsers(dest="command", required=True)
    weights = sub.add_parser("weights")
    weights.add_argument("agent")
    weights.add_argument("out")
    weights.add_argument("--seed", type=int, default=0)
    weights.add_argument("--perturb-clip-bn", action="store_true")
    weights.add_argument("--act", nargs=2, metavar=("REQUEST", "ACT_OUT"))
    weights.add_argument("--clip-fp16", action="store_true")
    weights.add_argument("--n-rotations", type=int, default=36)
    train = sub.add_parser("train")
    train.add_argument("agent")
    train.add_argument("out")
    train.add_argument("request")
    train.add_argument("trained_out")
    train.add_argument("--seed", type=int, default=0)
    train.add_argument("--perturb-clip-bn", action="store_true")
    train.add_argument("--n-rotations", type=int, default=36)
    train.add_argument("--steps", type=int, default=1)
    for name in ("act", "clip"):
        p = sub.add_parser(name)
        p.add_argument("agent")
        p.add_argument("ckpt")
        p.add_argument("request")
        p.add_argument("out")
        if name == "act":
            p.add_argument("--clip-fp16", action="store_true")
    args = parser.parse_args()
    os.environ.setdefault("CUDA_VISIBLE_DEVICES", "")
    ref = _import_reference(args.reference_dir)
    {"weights": cmd_weights, "act": cmd_act, "clip": cmd_clip, "train": cmd_train}[args.command](ref, args)


if __name__ == "__main__":
    main()
