"""The typed errors of equipose (public path); they live in ``equipose.core.errors``."""
from equipose.core.errors import *  # noqa: F401,F403
from equipose.core.errors import __all__  # noqa: F401
