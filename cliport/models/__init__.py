"""Networks: residual blocks and hourglass ResNets (``resnet``), the frozen shared CLIP (``clip_backbone``),
the spatial / semantic / two-stream nets (``streams``), the pick and place heads (``heads``), FFT
cross-correlation (``correlation``) and input normalisation (``preprocess``)."""
