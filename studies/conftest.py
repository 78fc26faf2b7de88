"""The product tests' shared fixtures (``tests/conftest.py``), for the study tests.

A conftest below the root may not load another as a plugin, so the fixtures are imported by module path;
pytest puts the repository root on ``sys.path`` because ``studies`` is a package.
"""

from tests.conftest import tiny_checkpoint, tiny_dataset_path  # noqa: F401 - fixtures, used by name
