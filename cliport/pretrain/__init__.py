"""Contrastive and dense image-text pretraining of the semantic stream's encoders on scenes the simulator renders
(``cliport-pretrain``), its probe, and the colour-transfer report of the unseen-colours experiment.

========== ==========================================================================================================
module     holds
========== ==========================================================================================================
vocabulary the captions' words (every colour and kit shape, objects, spatial words) and which are true of a crop
scenes     random tabletop scenes as plain data, a pure function of a seed
render     a scene built in the simulator, cut into top-down, oblique and relation crops, and its whole labelled map
cache      the rendered crops and maps on disk: shards written atomically, resumed, checked against their settings
batches    what a training step sees: crops, a fresh caption each, which captions are true of which crops
loss       CLIP's symmetric contrastive loss with every true caption a positive, and in-batch retrieval
dense      the dense objective (each map pixel against its scene's captions) and its probe on whole scenes
config     :class:`PretrainConfig` (defaults in configs/pretrain.toml, a [cpu] and a [cuda] table)
trainer    the run: render, train (resumable), write the weights, probe random against pretrained
checkpoint the open_clip-format output (weights file, open_clip config) and the resumable state
probe      zero-shot colour and shape retrieval on held-out scenes (crops, and pixels), seen and unseen apart
transfer   an agent's test episodes and swapped instructions split by whether an unseen colour is named
========== ==========================================================================================================

The weights it writes are an open_clip state dict that ``--clip-weights FILE --semantic-encoder NAME`` loads through
the path every CLIP weights file takes (:mod:`cliport.models.encoders.clip_weights`); the small architectures a CPU
can pretrain are open_clip model configs shipped with cliport (:mod:`cliport.models.encoders.clip_registry`).
See docs/pretraining.md.
"""
