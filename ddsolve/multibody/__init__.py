"""Multibody solvers: FETI-FETI (Chapter 3) and the hybrid method (Chapter 4)."""
from .interface import CONTACTS, GlobalInterface

__all__ = ["GlobalInterface", "CONTACTS"]
