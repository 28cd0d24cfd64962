"""The FOCAS2 Ethernet client: sessions, a pool of them, program transfer (gateway/codecs/focas/ parses)."""
