"""The URLB study: resumable runs (:mod:`.checkpoint`), the job graph (:mod:`.graph`), one driver (:mod:`.driver`)
and the Ray engine (:mod:`.engine`).

* a **run** is one pre-training or fine-tuning (:func:`sb3_cic.protocol.pretrain`,
  :func:`sb3_cic.protocol.finetune`): a :class:`~.run.Run` in, a run folder out. It checkpoints itself at episode
  boundaries and resumes from its last checkpoint; it knows nothing of Ray.
* the **job graph** is data: the runs of a study command, each fine-tuning depending on its
  pre-training.
* the **driver** checks a command's runs against the study folder before anything runs, records them and hands
  them to an executor: in this process (``sb3-cic protocol``) or the **engine**, the graph as Ray tasks with their
  resources and ``max_retries`` (``sb3-cic study``).

The study's folder layout (which folder holds which run) is :mod:`.layout`, read by the runs and the graph;
the settings of a study and what its folder records of them are :mod:`.settings`; what else the folder records
and how every command checks it (the pairing of fine-tunings with pre-trainings, each run's settings,
``study.json``, the lock of the driving command) is :mod:`.record`.

:mod:`.cli` holds ``sb3-cic protocol``, ``sb3-cic study`` and ``sb3-cic status``.

Nothing is imported here, so that the run code (``sb3_cic.protocol``) can import :mod:`.checkpoint`
without importing Ray.
"""
