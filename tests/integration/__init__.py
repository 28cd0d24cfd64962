"""Integration tests, one folder per feature as a user meets it (alarms, commands, copydata, jobs, mqtt,
opcua, security, simulator) plus the fault drills (drills); tests that cross features end to end (the CLI,
the README's walkthrough, the mirror, the bench harness) sit at the top. A new feature adds its own folder.
"""
