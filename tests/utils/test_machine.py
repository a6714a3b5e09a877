"""The environment a results row records: the processor as /proc/cpuinfo names it, versions, commit, command."""

from __future__ import annotations

import torch

from cliport.utils import machine

ZEN3 = """processor\t: 0
vendor_id\t: AuthenticAMD
cpu family\t: 25
model\t\t: 1
model name\t: AMD EPYC 7B13
flags\t\t: fpu sse2 avx avx2 fma

processor\t: 1
model name\t: another core, never read
"""


def test_cpu_description_reads_the_first_processor_and_its_vector_units(tmp_path) -> None:
    info = tmp_path / "cpuinfo"
    info.write_text(ZEN3)
    cpu = machine.cpu_description(str(info))
    assert (cpu["model"], cpu["vendor"], cpu["family"], cpu["model_number"]) == ("AMD EPYC 7B13", "AuthenticAMD", 25, 1)
    assert cpu["flags"] == ["avx2"]
    assert machine.cpu_line({**cpu, "cores": 2}) == "2-core AMD EPYC 7B13 (family 25, AVX2, no AVX-512)"
    info.write_text(ZEN3.replace("avx2 fma", "avx2 fma avx512f avx512_bf16"))
    cpu = machine.cpu_description(str(info))
    assert cpu["flags"] == ["avx2", "avx512f", "avx512_bf16"]
    assert machine.cpu_line({**cpu, "cores": 2}).endswith("(family 25, AVX-512)")


def test_a_machine_without_cpuinfo_still_names_its_processor(tmp_path) -> None:
    cpu = machine.cpu_description(str(tmp_path / "missing"))
    assert cpu["model"] and cpu["family"] is None and cpu["flags"] == []


def test_measurement_environment_records_versions_commit_and_command() -> None:
    env = machine.measurement_environment(["bench.py", "--lesson"])
    assert env["command"] == "bench.py --lesson"
    assert env["versions"]["torch"].split("+")[0] == torch.__version__.split("+")[0]
    assert env["threads"] == torch.get_num_threads() and env["cpu"]["cores"] >= 1
    assert env["commit"] is None or len(env["commit"]) >= 7
    assert env["cpu_line"] == machine.cpu_line(env["cpu"])
