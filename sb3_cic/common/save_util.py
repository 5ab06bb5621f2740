"""Reading a saved model before loading it: its attributes, and what explains a snapshot loaded by mistake."""

from __future__ import annotations

import contextlib
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
from stable_baselines3.common.save_util import json_to_data, open_path
from stable_baselines3.common.type_aliases import GymEnv

from sb3_cic.common.env_util import env_id_of, prepare_env
from sb3_cic.skills import SkillPrior
from sb3_cic.version import __version__


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
    reward module and the attributes, about half the size, that :meth:`~sb3_cic.ddpg.URLBDDPG.load` and
    ``load_pretrained`` read with fresh optimisers (fine-tuning starts with fresh ones anyway).

    :param path: the saved model (``.zip``)
    :param out: where to write the copy (default: over ``path``)
    :return: the path written
    """
    path = Path(path)
    out = path if out is None else Path(out)
    with zipfile.ZipFile(path) as archive:
        entries = [(info, archive.read(info)) for info in archive.infolist() if not is_optimizer_state(info.filename)]
    with tempfile.NamedTemporaryFile(dir=out.parent, suffix=".zip", delete=False) as file:
        with zipfile.ZipFile(file, "w", zipfile.ZIP_DEFLATED) as archive:
            for info, content in entries:
                archive.writestr(info, content)
    shutil.copymode(path, file.name)  # the source's permissions, not the temporary file's
    os.replace(file.name, out)
    return out


def package_version() -> str:
    """This package's version (saved with each model)."""
    return __version__


class SavedModel:
    """What :meth:`~sb3_cic.ddpg.URLBDDPG.load` reads of a saved model before loading it, to explain a mistake.

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
