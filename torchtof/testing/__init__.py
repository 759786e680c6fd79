"""Test oracles shared by the test suite and ``torchtof bench stability``.

:mod:`torchtof.testing.stability` builds the numerical stress matrix (every public module ×
float16/bfloat16/float32/float64 on edge-case inputs) and holds its tolerance table.
"""
