"""Fanuc FOCAS2 over Ethernet, sans I/O: frames, multi-command requests, the data they carry.

The facts (packet layout, function codes, encodings) come from others' protocol analysis: the
pyfocas package, diohpix/pyfanuc's notes and a C# client; docs/focas.md says which, and where
they disagree. Nothing here reads a socket: bytes in, frames and values out.
"""
