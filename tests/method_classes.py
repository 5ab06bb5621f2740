"""Every method class of the package (URLB's nine, MOSS, Fixed), for the tests that run each one."""

import sb3_cic.methods as methods
from sb3_cic import URLBDDPG

METHODS: list[type[URLBDDPG]] = [getattr(methods, name) for name in methods.__all__
                                 if isinstance(getattr(methods, name), type) and issubclass(getattr(methods, name), URLBDDPG)]
