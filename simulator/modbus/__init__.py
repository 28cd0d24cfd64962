"""The simulator's Modbus TCP face: a chiller beside the laser (chiller.py), served from a register image
(image.py) by an asyncio server on the gateway's server-side frames codec (face.py)."""

from simulator.modbus.chiller import CHILLER_MAP, Chiller
from simulator.modbus.face import DEFAULT_PORT, ModbusFace
from simulator.modbus.image import RegisterImage

__all__ = ["CHILLER_MAP", "DEFAULT_PORT", "Chiller", "ModbusFace", "RegisterImage"]
