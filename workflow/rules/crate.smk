# The results folder as a Provenance Run Crate (RO-Crate): every target ends with it. It
# covers every run sealed in the folder: the built-in experiment, and each study whose seal
# is there or that this call builds.
from mjtrial.files.layout import STUDIES


def crate_seals(wildcards):
    """The seals the crate covers. A study this call builds (`snakemake -c2 sensitivity`,
    `studies`, or its seal named as a target) is a dependency; a study sealed by an earlier
    call is read as it is on disk (`before_update`: no rule rebuilds it for the crate), so
    `snakemake -c2` never reruns a study, and the crate's inputs are the same either way.
    """
    targets = set(workflow.dag_settings.targets or ())
    seals = [str(LAYOUT.seal)]
    for study in STUDIES:
        seal = str(LAYOUT.study_seal(study))
        if {study, "studies", seal} & targets:
            seals.append(seal)
        elif Path(seal).exists():
            seals.append(before_update(seal))
    return seals


rule crate:
    input:
        seals=crate_seals,
    output:
        crate=LAYOUT.crate,
        source=directory(LAYOUT.source),
    log:
        LAYOUT.log("crate"),
    params:
        slice=config_slice("crate", config),
        code=stage_code_hash("crate"),
    run:
        run_script("crate", input, output, params, wildcards, threads, log, rule)
