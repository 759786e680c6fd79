"""Reconstructors: every one an ``nn.Module`` with ``forward(y (B, C, M)) -> x (B, C, n, n)``."""

from .correlation import CGI, DGI, TGI, cgi, dgi, g2, tgi
from .pinv import PseudoInverse, pseudo_inverse

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
]
