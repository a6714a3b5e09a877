"""The console scripts, one module each: cliport-tasks (``tasks``), cliport-demos (``demos``), cliport-train
(``train``), cliport-eval (``eval``), cliport-reproduce (``reproduce``), cliport-predict (``predict``),
cliport-import (``import_demos``), cliport-convert (``convert``), cliport-push (``push``) and cliport-pretrain
(``pretrain``); ``common`` holds their one-line errors and ``--version``. Each builds its parser without importing
torch or an agent, so that ``--help`` answers at once.
"""
