"""Acquisition: a plan (data) executed by an engine that emits records to its subscribers.

One concept per module; dependencies point down to :mod:`gonio.instrument` and :mod:`gonio.data`:

``gonio.acquisition.plan``
    what to measure: the plan TOML schema, validation, motion order, the procedure steps;
``gonio.acquisition.engine``
    executes a plan on the two devices, step by step, checkpointing every point;
``gonio.acquisition.subscribers``
    what listens to the engine: the journal writer, the progress display, the dataset writer;
``gonio.acquisition.live``
    the live view: a subscriber and a local read-only web page that shows the points as they arrive;
``gonio.acquisition.journal``
    the append-only JSON Lines journal (the checkpoint storage a run resumes from);
``gonio.acquisition.calibration``
    the measurement equation and the white standard's calibration table;
``gonio.acquisition.reduce``
    the reduction of a journal to the measured dataset (and the retry totals);
``gonio.acquisition.record``
    recording of both links to a transcript, and replay from it;
``gonio.acquisition.rundir``
    the run directory's files and its lock;
``gonio.acquisition.session``
    one session: devices, engine and subscribers on two links (live, recording or replaying).
"""

from gonio.acquisition.engine import Engine, RunResult
from gonio.acquisition.plan import Plan, PlanError, Procedure, load_plan, parse_plan
from gonio.acquisition.session import replay_session, run_session

__all__ = ["Engine", "RunResult", "Plan", "PlanError", "Procedure", "load_plan", "parse_plan",
           "run_session", "replay_session"]
