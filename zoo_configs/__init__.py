"""The rl-zoo yaml files of the methods (``<algo>.yml``, keys = env ids), installed as ``sb3_cic.zoo_configs``.

The command line finds them through the installed package (:data:`sb3_cic.zoo.CONFIG_DIR`), in a checkout and
from a wheel alike.
"""
