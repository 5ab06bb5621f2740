"""Helpers below the algorithms, as in sb3-contrib's ``common``: the algorithms and callbacks import them, they
import no algorithm.

* :mod:`.arguments`: argument checks (ranges, positive ints) and URLBDDPG's range table;
* :mod:`.env_util`: making an env ready for a URLB agent (skill wrapper, spaces), its Gymnasium id;
* :mod:`.save_util`: reading a saved model's attributes, explaining a snapshot loaded onto the wrong env or class;
* :mod:`.method`: a method's declaration (skill prior, reward module, fine-tuning skill choice, kept critic layers)
  and how the model builds its parts;
* :mod:`.skill_mixin`: the skill plumbing of an agent (set the skill, act on plain state observations);
* :mod:`.resumable`: the state a run checkpoint saves of callbacks and envs.
"""
