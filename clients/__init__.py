"""The service's clients and where their answers go: ``rgb2cloud client`` (``photos``), ``rgb2cloud stream``
(``stream``) and its sinks (``sinks``). Torch-free, and never imported by the service (``app``)."""
