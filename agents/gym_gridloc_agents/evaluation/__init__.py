"""Evaluation: the one episode loop (:mod:`~gym_gridloc_agents.evaluation.rollout`), the benchmark
(:mod:`~gym_gridloc_agents.evaluation.bench`; ``gridloc bench``/``bound``:
:mod:`~gym_gridloc_agents.evaluation.bench_command`; on a Ray cluster:
:mod:`~gym_gridloc_agents.evaluation.bench_cluster`), statistics
(:mod:`~gym_gridloc_agents.evaluation.stats`), tables and plots
(:mod:`~gym_gridloc_agents.evaluation.report`, :mod:`~gym_gridloc_agents.evaluation.curves`,
:mod:`~gym_gridloc_agents.evaluation.figures`)."""
