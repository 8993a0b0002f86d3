"""Research code apart from the product: how hard a sample-world dataset is, the sweep of
perception settings, the regeneration of docs/results.md and the breakdown of the
perception model's mistakes.

It builds on the product (``evaluate`` and every stage above it) and nothing in the product
imports it but the command line (``care sample make --measure``). Each study runs as
``python -m research.<module>`` or through its entry point in ``scripts/``.
"""
