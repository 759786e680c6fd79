"""Reconstructors: every one an ``nn.Module`` with ``forward(y (B, C, M)) -> x (B, C, n, n)``."""

from .bp import BasisPursuit, BPResult, basis_pursuit
from .correlation import CGI, DGI, TGI, cgi, dgi, g2, tgi
from .pinv import PseudoInverse, pseudo_inverse
from .tval3 import TVAL3, TVAL3Result, tval3
from .unrolled import UnrolledTVAL3

__all__ = [
    "CGI",
    "DGI",
    "TGI",
    "cgi",
    "dgi",
    "g2",
    "tgi",
    "PseudoInverse",
    "pseudo_inverse",
    "BasisPursuit",
    "BPResult",
    "basis_pursuit",
    "TVAL3",
    "TVAL3Result",
    "tval3",
    "UnrolledTVAL3",
]
