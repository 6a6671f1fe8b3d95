"""``triplesumo reproduce``: the whole reproduction protocol from one command, resumable.

The paper trains an Ant (3,000 epochs), then a second agent (20,000 epochs) to make "an ongoing
game", then adds Bug. Built that way literally, the match was no contest (env v1, measured): an
Ant trained against a random Spider learned nothing (a random Spider walks off the ring by itself
in 28 of 32 matches, so a passive Ant already "wins" 87.5 %), and a Spider then trained for
20,000 epochs against that frozen Ant won 82 % with Bug passive. Learning together from scratch
(env v2) ended in a standoff, and with a draw penalty the Ant learned to push while its Spider, shoved
back by it, never did (docs/notes/contest-log.md: seven attempts and what they measured). The stages here
teach each side to push on its own, check that the pair is a contest, and only then train Bug:

1. ``ant`` and ``spider``: each side alone learns (DDPG, ``train --learn ant=ddpg``) to push still
   opponents: every other agent passive, a body that neither walks off the ring by itself (as a
   random one does) nor shoves back (as a co-trained one does), for ``ant_epochs`` and
   ``spider_epochs``, on the pre-training reward ``pretrain`` (:data:`PRETRAIN_REWARD`): still -1, so
   that losing costs more than surviving (with the paper's -4 and gamma 0.99, still / (1 - gamma) =
   -400 = the loss reward, and being pushed out at any step is worth as much as surviving without
   winning; ``__post_init__`` refuses such a value), draw -200, so that a standoff costs more than
   trying, a 0.25 m dead zone on the per-axis signs and the per-opponent terms summed, so that the
   Spider, with two opponents, is paid for approaching and shoving as the Ant is. ``pair`` skips the
   stages and checks a given pair instead (``--pair zoo:ant zoo:spider``).
2. ``contest``: the pair on ``contest_epochs`` held-out starts (``contest_seed`` + i, apart from
   the Bug's test starts), three evaluations (``OUT/contest``): the Ant against a passive Spider,
   the Spider against a passive Ant and Bug (each must push an opponent out in at least
   :data:`PUSH_MIN` of the matches), and the match with Bug passive, whose team MWR must lie in
   :data:`CONTEST_BAND` (the team loses without Bug's help, but not hopelessly). The checks are played
   in that order, in blocks (:func:`~triplesumo.reproduce.protocol.play_contest`): the first that can no
   longer pass, whatever its other starts give, stops the contest, and the checks after it are not
   played; a pair that passes plays every start. ``contest.json`` holds each check and the verdict.
3. ``bug``: Bug trained with each algorithm x seed in that match, as the trials of
   :mod:`triplesumo.train.sweep` run here one after another (``OUT/bug/learn=bug=ALGO,seed=S``).
   **It refuses to start on a pair that failed the contest rule** (:class:`ContestError`); with
   ``tiny`` (2-epoch agents are no contest) the verdict is recorded and printed, not enforced.
   With ``ablations`` (``--ablations noise=gaussian still=-1``), stage ``ablations`` then trains
   the paper-preset DDPG Bug with each one change over the same seeds and env-step budget
   (``OUT/ablations/learn=bug=ddpg,ddpg.noise=gaussian,seed=S``).
4. ``evaluation``: every Bug (ablations included) plus the passive and random baselines on the
   same seeded test matches (``OUT/evaluation``, ``per_seed.csv``).
5. ``compare``: IQM with bootstrap intervals by trial (each algorithm, each ablation) and its
   plot (``OUT/compare``).

``--publish`` then ships the pre-trained Ant and Spider (``zoo:ant``, ``zoo:spider``, each manifest with the
contest check the pair passed), every algorithm's Bug as ``zoo:bug-<algo>`` (its seed with the highest training
MWR over the last 200 training matches: the test starts pick nothing) and, as ``zoo:bug``, that Bug of the
algorithm with the highest IQM test MWR across seeds; each Bug's manifest has its command, seed, env steps, the
code version, its test MWR with 95 % interval and how it was picked.

Time to skill comes from stage 3 itself: every Bug run evaluates its current policy every
``bug_eval_every`` env steps on the first ``bug_eval_epochs`` test matches of stage 4
(``train --eval-every``, ``eval.csv``), and the report gives, per algorithm and seed, the
env steps and training wall time until its test MWR first reached +0.2, with the curves
(``bug/test_mwr.png``).

A stage whose outputs exist and are complete is skipped; a killed one goes on where it
stopped (train runs resume from their last checkpoint, evaluations with ``resume``).
``reproduce.json`` records the stages done, their commands and the code version, and
``REPRODUCTION.md`` is written from the outputs each time. Redoing an earlier stage does
not invalidate later ones: delete their folders to redo them too.
"""

from triplesumo.reproduce.config import (
    ABLATION_ALIASES,
    CONTEST_BAND,
    PRETRAIN_REWARD,
    PROTOCOL_FIELDS,
    PUSH_MIN,
    RECORD_FILE,
    REPORT_FILE,
    RUN_OPTIONS,
    SKILL,
    ContestError,
    PairError,
    ReproduceConfig,
    Stage,
    ablation,
)
from triplesumo.reproduce.protocol import Protocol, contest_verdict, format_contest
from triplesumo.reproduce.reporting import DOCS_BEGIN, DOCS_END, embed_report, format_status, report, status
from triplesumo.reproduce.run import check_same_options, code_version, run_reproduce

__all__ = [
    "ABLATION_ALIASES", "CONTEST_BAND", "ContestError", "DOCS_BEGIN", "DOCS_END", "PRETRAIN_REWARD", "PairError",
    "PROTOCOL_FIELDS", "PUSH_MIN", "Protocol", "RECORD_FILE", "REPORT_FILE", "RUN_OPTIONS", "ReproduceConfig",
    "SKILL", "Stage", "ablation", "check_same_options", "code_version", "contest_verdict", "embed_report",
    "format_contest", "format_status", "report", "run_reproduce", "status"
]
