"""The FOCAS2 Ethernet driver (`driver: {type: focas}`): poll groups over a session pool."""
