"""The job-service harness of the job tests, for serial machines."""

from tests.integration.jobs.conftest import harness  # noqa: F401 - the fixture
