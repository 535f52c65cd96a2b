"""Elphel recordings: JP4/JP46/JPEG frames on disk, converted to TIFFs, quads and bursts."""

from __future__ import annotations

from elphel_host.recordings.convert import Converted, ConvertResult, Failure, convert

__all__ = ["ConvertResult", "Converted", "Failure", "convert"]
