"""Research tooling: the quality report, stored scores, diagnostics and view novelty.

The product (``contract``, ``app``, ``trainer``, ``cli``) never imports this package,
and the serving image leaves it out.
"""
