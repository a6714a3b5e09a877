"""Numbers shipped with the package as data: the CLIPort and Transporter Networks papers' published results
(``published_results.json``) and the language-blind ceilings of the CLIPort tasks (``blind_ceilings.json``, written
by ``scripts/oracle_table.py --blind --json``). :mod:`cliport.evaluation.published` reads them. The reference code,
the original CLIPort that the parity tests compare with, is another thing (``CLIPORT_REFERENCE_DIR``)."""
