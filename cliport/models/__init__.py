"""Networks: the trainable nets, the pick and place heads around them, and the frozen pretrained encoders.

Every net, the reference CLIPort class it reproduces (files under the reference's cliport/models/; the
stream classes are in its streams/ folder) and the agents that use it:

================== ================= ========================================================= =====================
class              module            reproduces the reference's                                used by agents
================== ================= ========================================================= =====================
TransporterNet     transporter       ResNet43_8s (resnet.py) after its preprocessing           transporter_only
ResNet43_8s        resnet            ResNet43_8s (resnet.py)                                   transporter_only
ResNet45_10s       resnet            ResNet45_10s (resnet_lat.py)                              two_stream, rn50_bert
LingUNetDecoder    lingunet          CLIPLingUNet (clip_lingunet.py)                           clip_only
LingUNetLatDecoder lingunet          CLIPLingUNetLat (clip_lingunet_lat.py)                    two_stream
                                     RN50BertLingUNetLat (rn50_bert_lingunet_lat.py)           rn50_bert
SemanticNet        semantic          OneStream{Attention,Transport}LangFusion                  clip_only
TwoStreamNet       two_stream        TwoStream{Attention,Transport}LangFusionLat               two_stream, rn50_bert
PickHead           heads             Attention (core/attention.py)                             all
PlaceHead          heads             Transport (core/transport.py)                             all
FrozenCLIP         clip_encoder      the frozen CLIP RN50 in its nets (core/clip.py)           two_stream, clip_only
FrozenRN50BERT     rn50_bert_encoder the frozen ResNet-50 and DistilBERT in its RN50-BERT nets rn50_bert
================== ================= ========================================================= =====================

Other modules: ``blocks`` (residual and U-Net blocks, the stream fusions), ``encoders`` (the
:class:`~cliport.models.encoders.FrozenEncoder` base and :class:`~cliport.models.encoders.EncoderNet`, the
base of the nets that read one), ``clip_registry`` / ``clip_weights`` / ``clip_tokenizer`` / ``clip_vit``
(open_clip model names, weights, tokenizer, ViT adapter), ``rn50_trunk`` / ``distilbert`` (RN50-BERT's
parts and their weights), ``weights`` (weight files shared by the encoders), ``correlation`` (FFT
cross-correlation), ``rotation`` (kornia's rotation as the reference computes it), ``preprocess`` (input
normalisation), ``cuda_graphs`` and ``reference_names`` (the reference's state-dict names of our tensors).
"""
