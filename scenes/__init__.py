"""Reading scenes: every layout the trainer and ``convert-dataset`` read, into one ``SceneData``.

Below both the trainer (``smokeseer``) and the converters (``interop``), above ``contracts``:
``scenes.load.load_scene`` picks the reader (a generated dataset, the official SmokeSeer
layouts, or a capture), and every reader gives OpenCV world-to-camera matrices, intrinsics at
the working resolution, images as float arrays in [0, 1] and normalised times. Malformed input
raises ``DatasetError`` naming the file and the field, so every command prints one line.
"""
