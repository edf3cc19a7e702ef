"""What several commands share: argparse types for numeric options (:mod:`.args`), the progress line
(:mod:`.progress`), the result's summary on the terminal (:mod:`.summary`), what calibrate and check
read beside a capture's blobs (:mod:`.inputs`), the batch commands' memory policy
(:mod:`.batch_memory`) and the exit codes every command shares (:mod:`.exits`)."""
