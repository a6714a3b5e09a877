"""The lowest layer, used by every other: settings read from ``configs/*.toml`` and turned into flags
(``config``), atomic JSON, torch and safetensors files (``files``), the run folder's layout (``run_dir``), the
device choice (``device``), TensorBoard writers (``tensorboard``), reading other people's pickles and torch archives
without running their code (``safe_pickle``), and ``hf://org/name`` runs from the Hugging Face cache (``hub``).
"""
