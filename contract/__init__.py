"""What the service and the trainer share: model cards, the generator spec, depth codec, geometry, runtime.

Torch-free and small on purpose: the service imports nothing else of ours, and the
serving image carries this package and ``app`` only.
"""
