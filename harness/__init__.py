"""What the tests and the benchmarks share, kept out of the product packages and the serving image.

``harness.service`` starts the real service as a child process on a loopback port and reads
what a client or an operator would measure of it.
"""
