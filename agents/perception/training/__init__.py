"""Training the learned circle detector (:mod:`agents.perception.learned`) on the CPU.

- :mod:`~agents.perception.training.data` (numpy and OpenCV only): shards of frames with their
  circles, the network's targets, augmentation, a user's own labelled frames.
- :mod:`~agents.perception.training.model` and :mod:`~agents.perception.training.train` (PyTorch,
  the optional ``train`` extra): the two networks, the training loop and the ONNX export.
- ``python -m agents.perception.training`` is the command line (``--help``).

Nothing else in the package imports this subpackage's PyTorch modules: the detector runs the
exported ONNX files without PyTorch.
"""
