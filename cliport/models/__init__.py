"""Networks: the trainable nets and the pick and place heads around them; the frozen pretrained encoders they
read are the subpackage :mod:`cliport.models.encoders`.

Every net, the reference CLIPort class it reproduces (files under the reference's cliport/models/; the
stream classes are in its streams/ folder) and the agents that use it:

================== ========================== =============================================== =====================
class              module                     reproduces the reference's                      used by agents
================== ========================== =============================================== =====================
TransporterNet     transporter                ResNet43_8s (resnet.py) after its preprocessing transporter_only
ResNet43_8s        resnet                     ResNet43_8s (resnet.py)                         transporter_only
ResNet45_10s       resnet                     ResNet45_10s (resnet_lat.py)                    two_stream, rn50_bert
LingUNetDecoder    lingunet                   CLIPLingUNet (clip_lingunet.py)                 clip_only
LingUNetLatDecoder lingunet                   CLIPLingUNetLat (clip_lingunet_lat.py)          two_stream
                                              RN50BertLingUNetLat (rn50_bert_lingunet_lat.py) rn50_bert
SemanticNet        semantic                   OneStream{Attention,Transport}LangFusion        clip_only
TwoStreamNet       two_stream                 TwoStream{Attention,Transport}LangFusionLat     two_stream, rn50_bert
PickHead           heads                      Attention (core/attention.py)                   all
PlaceHead          heads                      Transport (core/transport.py)                   all
LateralFusion      fusion                     FusionConvLat (core/fusion.py)                  two_stream, rn50_bert
AddFusion          fusion                     FusionAdd (core/fusion.py)                      two_stream, rn50_bert
ConvFusion         fusion                     FusionConv (core/fusion.py)                     two_stream, rn50_bert
language_gate      fusion                     FusionMult (core/fusion.py)                     the language agents
FrozenCLIP         encoders.clip_encoder      the frozen CLIP RN50 in its nets (core/clip.py) two_stream, clip_only
FrozenRN50BERT     encoders.rn50_bert_encoder the frozen ResNet-50 and DistilBERT of its      rn50_bert
                                              RN50-BERT nets
================== ========================== =============================================== =====================

Other modules: ``blocks`` (residual and U-Net blocks), ``encoder_net`` (:class:`EncoderNet
<cliport.models.encoder_net.EncoderNet>`, the base of the nets that read a frozen encoder, with each net's own
copy of its batch-norm statistics), ``correlation`` (FFT cross-correlation), ``rotation`` (kornia's rotation as
the reference computes it), ``preprocess`` (input normalisation), ``cuda_graphs`` and ``reference_names`` (the
reference's state-dict names of our tensors). The encoders' own modules are listed in
:mod:`cliport.models.encoders`.
"""
