"""Fine-tuning a pre-trained model: what loading keeps and resets, and the skill-selection callback it adds.

The one place of that logic: :meth:`~sb3_cic.ddpg.URLBDDPG.load_pretrained` and ``learn`` call it, and so does
the protocol's fine-tuning run (:func:`sb3_cic.protocol.finetune`).
"""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback

from sb3_cic.callbacks import SkillSelectionCallback
from sb3_cic.common.env_util import env_id_of

#: what fine-tuning may keep of the pre-trained critic (see :func:`start_finetuning`)
FINETUNE_CRITIC = ("trunk", "all", "none")


def start_finetuning(model: Any, env: GymEnv | str, finetune_critic: str) -> None:
    """Turn a loaded pre-trained ``model`` into the start of a fine-tuning on ``env``.

    Keeps the actor, the reward module and the critic (``finetune_critic``: "trunk" keeps its trunk and
    re-initialises the heads, as URLB; "all" keeps it whole; "none" builds a new one); the target critic
    starts as a copy of the critic. Fresh optimisers, no fine-tuning skill yet, step 0, and the replay
    buffer's relabel hook as the model's reward mode says (``reward_free=False``: none).

    :param model: the :class:`~sb3_cic.ddpg.URLBDDPG` as loaded (``reward_free=False``, on ``env``)
    :param env: the task environment (id, env or VecEnv)
    :param finetune_critic: "trunk", "all" or "none"
    """
    if finetune_critic not in FINETUNE_CRITIC:
        raise ValueError(f"finetune_critic must be 'trunk', 'all' or 'none', got {finetune_critic!r}")
    model.env_id = env_id_of(env) or model.env_id
    if finetune_critic == "trunk":
        model.critic.reset_heads()
    elif finetune_critic == "none":
        model.policy.critic = model.critic = model.policy.make_critic()
    model.critic_target.load_state_dict(model.critic.state_dict())
    policy = model.policy
    lr = model.lr_schedule(1)
    model.actor.optimizer = policy.optimizer_class(model.actor.parameters(), lr=lr, **policy.optimizer_kwargs)
    model.critic.optimizer = policy.optimizer_class(model.critic.parameters(), lr=lr, **policy.optimizer_kwargs)
    model._critic_params = list(model.critic.parameters())
    model.finetune_skill = None
    model.num_timesteps = 0
    model._n_updates = 0
    model._episode_num = 0
    model._install_relabel()


def finetune_callbacks(model: Any, callbacks: list[BaseCallback]) -> list[BaseCallback]:
    """``callbacks`` with the method's skill-selection callback first, when ``model`` fine-tunes a skill-based
    method and none of ``callbacks`` (or of the :class:`~stable_baselines3.common.callbacks.CallbackList` among
    them) selects the skill already.

    :param model: the :class:`~sb3_cic.ddpg.URLBDDPG` about to learn
    :param callbacks: the callbacks given to ``learn``
    """
    if model.reward_free or model.skill_prior is None:
        return callbacks
    flat = [c for cb in callbacks for c in (cb.callbacks if isinstance(cb, CallbackList) else [cb])]
    if any(isinstance(c, SkillSelectionCallback) for c in flat):
        return callbacks
    selection = model.make_finetune_callback()
    return callbacks if selection is None else [selection, *callbacks]


def with_finetune_callback(model: Any, callback: MaybeCallback) -> MaybeCallback:
    """``learn``'s ``callback`` with :func:`finetune_callbacks`'s selection added (as a ``CallbackList``), if any.

    :param model: the model about to learn
    :param callback: ``learn``'s callback argument
    """
    given: list[Any] = callback if isinstance(callback, list) else [] if callback is None else [callback]
    callbacks = finetune_callbacks(model, given)
    return callback if callbacks is given else CallbackList(callbacks)
