"""Saving and loading a URLB agent: reading a saved model before loading it (its attributes, what explains a
snapshot loaded by mistake), networks-only snapshots and :class:`SaveLoadMixin`, the algorithm's save/load."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import warnings
import zipfile
import zlib
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import torch as th
from stable_baselines3.common.save_util import json_to_data, open_path, recursive_getattr
from stable_baselines3.common.type_aliases import GymEnv

from sb3_cic.common.env_util import env_id_of, prepare_env
from sb3_cic.skills import SkillPrior
from sb3_cic.version import __version__


#: the entry by which a networks-only snapshot says what it is (:func:`networks_only`)
NETWORKS_ONLY_ENTRY = "networks_only.txt"
NETWORKS_ONLY_NOTE = "A snapshot of the networks without the optimisers' states: loaded with fresh optimisers.\n"

#: what reading a damaged zip file raises (a truncated download, a file cut short by a full disk...)
DAMAGED_ZIP: tuple[type[Exception], ...] = (zipfile.BadZipFile, EOFError, zlib.error)


@contextlib.contextmanager
def quiet_tensor_reads() -> Iterator[None]:
    """Within the block, torch's warning about the pickle protocol of a damaged tensor entry is not shown (the
    entry is reported as unreadable instead, :func:`check_tensors`)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Detected pickle protocol")
        yield


def _damaged(path: Any, error: BaseException) -> ValueError:
    return ValueError(f"{path} is not a readable zip file ({error}): a damaged or truncated file, not a saved model")


@contextlib.contextmanager
def _archive(path: Any) -> Iterator[zipfile.ZipFile]:
    """The zip archive of a saved model (``.zip`` added when missing, as SB3's ``load``); a file object is left at
    its position; a damaged zip is a ``ValueError`` naming the file."""
    file = open_path(path, "r", suffix="zip")
    start = file.tell()
    try:
        with zipfile.ZipFile(file) as archive:
            yield archive
    except DAMAGED_ZIP as error:
        raise _damaged(path, error) from None
    finally:
        if file is path:
            file.seek(start)
        else:
            file.close()


def read_saved_data(path: Any, custom_objects: dict[str, Any] | None = None) -> dict[str, Any]:
    """The saved attributes of a model file (its ``data`` entry only; the networks are not read); a file that is no
    saved model (not a zip, no ``data`` entry, bad JSON) is a ``ValueError`` naming it and what is wrong.

    :param path: a path (``.zip`` added when missing, as SB3's ``load``) or a file object (left at its position)
    :param custom_objects: see SB3's ``load``
    """
    with _archive(path) as archive:
        if "data" not in archive.namelist():
            raise ValueError(f"{path} holds no saved model data (no 'data' entry): not a saved model")
        raw = archive.read("data")
    try:
        return json_to_data(raw.decode(), custom_objects=custom_objects)
    except ValueError as error:  # JSONDecodeError, UnicodeDecodeError
        raise ValueError(f"{path} is not a readable saved model: its 'data' entry is not valid JSON ({error})") from None


def is_networks_only(path: Any) -> bool:
    """Whether a model file is a networks-only snapshot (:func:`networks_only`): it says so (its
    :data:`NETWORKS_ONLY_ENTRY`), or, written before it did, it holds no optimiser state at all.

    :param path: a path or a file object (left at its position)
    """
    with _archive(path) as archive:
        names = archive.namelist()
    return NETWORKS_ONLY_ENTRY in names or not any(is_optimizer_state(name) for name in names if name.endswith(".pth"))


def check_tensors(path: Any) -> None:
    """``ValueError`` naming the first tensor entry (``policy.pth``...) of a saved model that torch cannot read with
    ``weights_only=True``. torch's own message is not passed on: it suggests ``weights_only=False``, which runs any
    code a file from elsewhere holds.

    :param path: a path or a file object (left at its position)
    """
    with _archive(path) as archive:
        for name in archive.namelist():
            if not name.endswith(".pth"):
                continue
            try:
                with archive.open(name) as entry, quiet_tensor_reads():
                    th.load(entry, map_location="cpu", weights_only=True)
            except DAMAGED_ZIP as error:
                raise _damaged(path, error) from None
            except Exception as error:  # noqa: BLE001  (whatever torch raises: the file is no saved tensors)
                raise ValueError(
                    f"{path} is not a readable saved model: its {name} entry holds no tensors torch reads safely "
                    f"({type(error).__name__}); the file is damaged or not a saved model"
                ) from None


def check_saved_model(path: Any, custom_objects: dict[str, Any] | None = None) -> SavedModel:
    """Read a saved model's attributes and tensors without building it: a ``ValueError`` naming the file and what is
    wrong for a damaged file, another library's model (:class:`SavedModel`) or unreadable tensors
    (:func:`check_tensors`); the model's :class:`SavedModel` otherwise.

    :param path: a path or a file object
    :param custom_objects: see SB3's ``load``
    """
    saved = SavedModel(read_saved_data(path, custom_objects), source=path)
    check_tensors(path)
    return saved


def is_optimizer_state(name: str) -> bool:
    """Whether a saved model's state dict (``actor.optimizer``) or its file (``actor.optimizer.pth``) is an
    optimiser's state."""
    return name.removesuffix(".pth").endswith("optimizer")


def networks_only(path: str | Path, out: str | Path | None = None) -> Path:
    """Copy a saved model without its optimiser states (``*optimizer.pth``): a snapshot of the networks, the
    reward module and the attributes, about half the size, that :meth:`SaveLoadMixin.load` and
    ``load_pretrained`` read with fresh optimisers (fine-tuning starts with fresh ones anyway). The copy says what
    it is (a :data:`NETWORKS_ONLY_ENTRY`) and forgets the tensorboard folder of the machine it was trained on
    (``tensorboard_log``: None), so that a snapshot to share names no local path. A file that this function wrote
    is left as it is when ``out`` is the file itself (its bytes, and so the sha256 a study recorded of it, kept).

    :param path: the saved model (``.zip``)
    :param out: where to write the copy (default: over ``path``)
    :return: the path written
    """
    path = Path(path)
    out = path if out is None else Path(out)
    with zipfile.ZipFile(path) as archive:
        if out.resolve() == path.resolve() and NETWORKS_ONLY_ENTRY in archive.namelist():
            return out
        entries = [(info, archive.read(info)) for info in archive.infolist() if not is_optimizer_state(info.filename)]
    with tempfile.NamedTemporaryFile(dir=out.parent, suffix=".zip", delete=False) as file:
        with zipfile.ZipFile(file, "w", zipfile.ZIP_DEFLATED) as archive:
            for info, content in entries:
                if info.filename == "data":
                    content = _without_tensorboard_log(content)
                if info.filename != NETWORKS_ONLY_ENTRY:
                    archive.writestr(info, content)
            archive.writestr(NETWORKS_ONLY_ENTRY, NETWORKS_ONLY_NOTE)
    shutil.copymode(path, file.name)  # the source's permissions, not the temporary file's
    os.replace(file.name, out)
    return out


def _without_tensorboard_log(data: bytes) -> bytes:
    """A saved model's ``data`` (SB3's JSON of its attributes) with ``tensorboard_log`` set to None."""
    attributes = json.loads(data)
    if attributes.get("tensorboard_log") is None:
        return data
    attributes["tensorboard_log"] = None
    return json.dumps(attributes, indent=4).encode()


def package_version() -> str:
    """This package's version (saved with each model)."""
    return __version__


class SavedModel:
    """What :meth:`SaveLoadMixin.load` reads of a saved model before loading it, to explain a mistake.

    A model of another library (a stock SB3 ``DDPG``, whose policy is not one of sb3-cic's) or without the
    attributes of a saved model is a ``ValueError`` naming ``source``.

    :param data: the saved attributes (:func:`read_saved_data`)
    :param source: the file, for the messages
    """

    def __init__(self, data: dict[str, Any], source: Any = "the file") -> None:
        self.data = data
        policy = data.get("policy_class")
        if isinstance(policy, type) and not policy.__module__.startswith("sb3_cic."):
            raise ValueError(
                f"{source} is not an sb3-cic model: its policy is {policy.__module__}.{policy.__qualname__} (a model of "
                "another library, e.g. stock SB3); sb3-cic loads the models its own classes saved (URLBDDPG, CIC...)"
            )
        try:
            self.obs_dim = int(data["observation_space"].shape[0])
            self.action_shape = tuple(data["action_space"].shape)
        except (KeyError, AttributeError, TypeError, IndexError) as error:
            raise ValueError(f"{source} is not a saved sb3-cic model: no readable observation and action spaces "
                             f"({type(error).__name__}: {error})") from None
        self.algorithm: str | None = data.get("algorithm")
        self.prior: SkillPrior | None = data.get("skill_prior")
        self.skill_dim = 0 if self.prior is None else self.prior.dim

    def describe(self) -> str:
        """``"the snapshot (CIC, pre-trained on URLB/walker-v0: state 24 + skill 64, action 6)"``."""
        skill = f" + skill {self.skill_dim}" if self.skill_dim else ""
        where = f"pre-trained on {self.data['env_id']}: " if self.data.get("env_id") else ""
        action = int(np.prod(self.action_shape))
        state = self.obs_dim - self.skill_dim
        return f"the snapshot ({self.algorithm or 'a model'}, {where}state {state}{skill}, action {action})"

    def version_note(self) -> str:
        """A note on the package version that saved the snapshot when it is not this one (else empty)."""
        saved = self.data.get("package_version")
        if saved == package_version():
            return ""
        return f" (saved by {'sb3-cic ' + saved if saved else 'an earlier sb3-cic'}; this is sb3-cic {package_version()})"

    def check(self, cls: type, env: GymEnv | str | None) -> GymEnv | str | None:
        """:meth:`check_class`, then :meth:`check_env` unless ``env`` is None; return the env to load onto.

        :param cls: the class loading the snapshot
        :param env: environment id, environment or VecEnv (None: none)
        """
        self.check_class(cls)
        return None if env is None else self.check_env(env)

    def check_class(self, cls: type) -> None:
        """``ValueError`` unless the snapshot was saved by ``cls``, one of its bases or a subclass of them.

        :param cls: the class loading the snapshot
        """
        names = {c.__name__ for c in cls.__mro__}
        if self.algorithm is not None and self.algorithm not in names:
            raise ValueError(
                f"{self.describe()} is a {self.algorithm} model: use {self.algorithm}.load_pretrained "
                f"(or {self.algorithm}.load), not {cls.__name__}'s{self.version_note()}"
            )

    def check_env(self, env: GymEnv | str) -> GymEnv:
        """``env`` prepared with the saved skill prior, or a ``ValueError`` saying how it differs from the snapshot's.

        :param env: environment id, environment or VecEnv
        """
        name = env_id_of(env) or type(env).__name__
        try:
            env = prepare_env(env, self.prior, self.data.get("skill_resample_every", 50), self.data.get("multi_input", False))
        except ValueError as error:
            if "skill_dim" not in str(error):
                raise
            raise ValueError(
                f"{self.describe()}: {error}; pass the plain env (the model adds its own skill){self.version_note()}"
            ) from error
        obs_dim, action_shape = env.observation_space.shape[0], env.action_space.shape
        if obs_dim != self.obs_dim or action_shape != self.action_shape:
            raise ValueError(
                f"{self.describe()} cannot act on {name} (state {obs_dim - self.skill_dim}, action "
                f"{int(np.prod(action_shape))}): fine-tune a snapshot pre-trained on {name}'s domain{self.version_note()}"
            )
        return env

class SaveLoadMixin:
    """What :class:`~sb3_cic.ddpg.URLBDDPG` saves and how it loads, mixed in before SB3's algorithm.

    Saved: SB3's state dicts plus the reward module and its optimiser (built in ``_setup_model``, excluded from
    pickling). ``load`` checks the snapshot against the class and env first (:class:`SavedModel`); a
    networks-only snapshot (:func:`is_networks_only`) loads through its own path, with the fresh optimisers'
    states in place of the saved ones, and SB3's ``set_parameters`` stays as strict as SB3's for every other use.
    """

    #: the attributes SB3 pickles that hold a reward module or its parameters (rebuilt in ``_setup_model``)
    _unsaved: tuple[str, ...] = ("reward_module", "_critic_params", "_critic_target_params", "_update_metrics", "_compiled_step")

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), *self._unsaved]  # type: ignore[misc]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()  # type: ignore[misc]
        if getattr(self, "reward_module", None) is not None:
            state_dicts += ["reward_module", "reward_module.optimizer"]
        return state_dicts, variables

    def set_parameters(self, load_path_or_dict: Any, exact_match: bool = True, device: th.device | str = "auto") -> None:
        """SB3's (a missing object with ``exact_match``: ``ValueError``). Called by :meth:`load` on a networks-only
        snapshot, it first adds the fresh optimisers' states (only there: the flag :meth:`load` sets is used once)."""
        if self.__dict__.pop("_load_fresh_optimizers", False) and isinstance(load_path_or_dict, dict):
            names = self._get_torch_save_params()[0]
            fresh = {name: recursive_getattr(self, name).state_dict() for name in names if is_optimizer_state(name)}
            load_path_or_dict = {**fresh, **load_path_or_dict}
        super().set_parameters(load_path_or_dict, exact_match=exact_match, device=device)  # type: ignore[misc]

    @classmethod
    def load(
        cls,
        path: Any,
        env: GymEnv | str | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ) -> Any:
        """Load a saved model (see SB3's ``load``); ``env`` may be an id and is wrapped with the saved skill prior.
        A snapshot of another method or env is a ``ValueError`` that says so (:class:`SavedModel`); a networks-only
        snapshot (:func:`networks_only`) loads with fresh optimisers.
        """
        from sb3_cic.common.arguments import check_ranges
        from sb3_cic.policies import normalize_policy_kwargs

        if "policy_kwargs" in kwargs:  # compared with the saved ones, which are normalised
            kwargs["policy_kwargs"] = normalize_policy_kwargs(kwargs["policy_kwargs"])
        check_ranges(kwargs, cls.loaded_argument_ranges())
        saved = SavedModel(read_saved_data(path, custom_objects), source=path)
        env = saved.check(cls, env)
        if is_networks_only(path):
            kwargs["_load_fresh_optimizers"] = True  # read once by set_parameters
        try:
            with quiet_tensor_reads():
                model = super().load(  # type: ignore[misc]
                    path, env=env, device=device, custom_objects=custom_objects,
                    print_system_info=print_system_info, force_reset=force_reset, **kwargs,
                )
        except (RuntimeError, ValueError, KeyError) as error:  # the saved state dicts do not fit this class's
            # (or a damaged entry); SB3's load answers set_parameters' ValueError with a KeyError of its DQN patch:
            # the ValueError says why
            check_tensors(path)
            cause = error.__context__ if isinstance(error, KeyError) and error.__context__ is not None else error
            raise ValueError(f"{saved.describe()} does not fit {cls.__name__}: {cause}{saved.version_note()}") from error
        except Exception:  # a damaged tensor entry: named, without torch's advice to unpickle it
            check_tensors(path)
            raise
        model.package_version = package_version()  # what will save it next
        return model

