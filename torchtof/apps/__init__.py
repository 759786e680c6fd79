"""The command-line applications of ``torchtof``: the demos, ``reproduce`` and the benchmarks.

They use the library (``torchtof.scenes`` → ``operators`` → ``sensor`` → ``bucket`` →
``recon`` → ``metrics``) and :mod:`torchtof.report`; the library never imports them.
"""
