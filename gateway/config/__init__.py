"""Configuration: the file models (pydantic) and YAML loading with located errors."""
