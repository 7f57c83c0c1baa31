# What every run shares, an experiment's or a benchmark's (LAYOUT is its results folder): how
# a job runs its stage's script, and the safekeeping of the results (mjtrial.files.safekeeping).
import sys
from pathlib import Path

from mjtrial.files.layout import script_path
from mjtrial.files.safekeeping import Snapshot, remove_stale_temporaries
from mjtrial.provenance.recording_folders import damaged_folders
from mjtrial.workflow_script import (
    cancel_scheduler_timers,
    failure_reasons,
    import_late_stages,
    mark_workflow_process,
    run_in_process,
)

# A job in a process of its own ends with the Snakemake process that started it.
mark_workflow_process()


# The states and register jobs run first, alone, before the rollouts: the later stages' imports
# beside them would only slow them (one interpreter lock; their wall was 2.5 times their CPU), so the
# imports begin with the first job after them that runs here (the first condition's gather,
# while the slower condition's rollout still runs in its own process).
FIRST_SCRIPTS = {"states", "register"}


def run_script(
    script, input, output, params, wildcards, threads, log, rule_name, config=None
):
    """Run `workflow/scripts/<script>.py` for a job inside Snakemake's own process (a rule's
    `run:` block; profiles/default/config.yaml sets `force-use-threads`, or Snakemake would
    start a Snakemake process per such job). The light stages run so: a process of their own
    would cost more in start-up and imports than their work (mjtrial.workflow_script).
    """
    if script not in FIRST_SCRIPTS:
        import_late_stages()
    run_in_process(
        script_path(script),
        input=input,
        output=output,
        params=params,
        wildcards=wildcards,
        threads=threads,
        logs=log,
        rule_name=rule_name,
        config=config,
    )


SAFEKEEPING = Snapshot(LAYOUT.root, logs=LAYOUT.logs_dir, workdir=Path.cwd())


def say_removed(temporaries):
    for path in temporaries:
        print(f"mjtrial: removed {path}, left by a killed job", file=sys.stderr)


def recover_killed_run():
    """Whatever the run does next (even nothing), put back what a killed run had removed: in
    the main Snakemake process only, never in a cluster job's."""
    recovery = SAFEKEEPING.recover()
    if recovery is None:
        return
    if recovery.restored:
        print(
            f"mjtrial: the last run was killed; put back {len(recovery.restored)} output(s) it "
            f"had removed: {', '.join(map(str, recovery.restored))}",
            file=sys.stderr,
        )
    say_removed(recovery.removed)
    if recovery.error:
        print(
            f"mjtrial: the snapshot a killed run left could not be used ({recovery.error}); "
            f"it is kept in {recovery.set_aside} and this run goes on without it",
            file=sys.stderr,
        )


def say_damaged_folders():
    """A folder of recordings is one output: Snakemake sees a file deleted inside it as
    nothing to do, so each one is named here, with the command that rebuilds it."""
    for problem in damaged_folders(LAYOUT.root):
        print(f"mjtrial: {problem}", file=sys.stderr)


if workflow.is_main_process:
    recover_killed_run()
    say_damaged_folders()


def on_start():
    """Clear what killed jobs left and take the snapshot before any job removes an output."""
    if "note_design_deviation" in globals():  # an experiment's run (common.smk)
        note_design_deviation()
    say_removed(remove_stale_temporaries(LAYOUT.root))
    try:
        SAFEKEEPING.take()
    except OSError as err:
        sys.exit(
            f"mjtrial: could not snapshot {LAYOUT.root} before the run ({err}); no job was "
            "started, so nothing was removed"
        )


def on_success():
    """Drop the snapshot; end Snakemake's pending scheduler timers, which would hold its exit
    up to a second (`mjtrial.workflow_script.cancel_scheduler_timers`)."""
    SAFEKEEPING.drop()
    cancel_scheduler_timers()


def on_error():
    """Put back every output the failed run removed or rebuilt, and say so: the folder is
    the last good run's (a job that succeeded may not fit what the failed one left). Then say
    why each job failed, from its log, so the console ends on the reason
    (mjtrial.workflow_script.failure_reasons)."""
    failed = getattr(workflow.scheduler, "failed", None) or ()
    reasons = failure_reasons(log for job in failed for log in job.log)
    restored = SAFEKEEPING.restore(replaced=True)
    SAFEKEEPING.drop()
    if restored:
        print(
            f"mjtrial: a job failed; the previous results were put back unchanged: "
            f"{', '.join(map(str, restored))}",
            file=sys.stderr,
        )
    for reason in reasons:
        print(reason, file=sys.stderr)
