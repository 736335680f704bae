"""Sizes in bytes as the messages about memory and disk write them."""


def format_bytes(size: int | float) -> str:
    """`1.5 GiB`, `12.3 MiB`, `640 bytes` (`over 1024 EiB` beyond that)."""
    if size >= 2**70:
        return "over 1024 EiB"
    units = ("EiB", "PiB", "TiB", "GiB", "MiB", "KiB")
    for unit, scale in zip(units, (2**60, 2**50, 2**40, 2**30, 2**20, 2**10)):
        if size >= scale:
            return f"{size / scale:.3g} {unit}"
    return f"{int(size)} bytes"


__all__ = ["format_bytes"]
