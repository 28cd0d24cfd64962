"""Configuration: the file models (pydantic) and YAML loading with located errors.

The models form one import cycle: mapping embeds jobs, jobs embeds validation,
and validation derives from mapping.Strict. Importing mapping first, whichever
module is asked for, lets the cycle resolve.
"""

from gateway.config import mapping as _mapping  # noqa: F401  (import order, see above)
