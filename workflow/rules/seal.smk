# The last rule: the sha256 of every output, report and figures included, so that
# `mjtrial verify` sees an edit to any of them.
rule seal:
    input:
        sealed_inputs,
        registration=LAYOUT.registration,
    output:
        seal=LAYOUT.seal,
    log:
        LAYOUT.log("seal"),
    params:
        folders=sealed_folders,
        code=stage_code_hash("seal"),
    run:
        run_script("seal", input, output, params, wildcards, threads, log, rule)
