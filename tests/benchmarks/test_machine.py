"""benchmarks.machine: the provenance block every results JSON carries."""
import json

import numpy as np

from benchmarks.machine import cpu_model_and_flags, machine_info

X86 = """processor\t: 0
model name\t: AMD EPYC 7B13
flags\t\t: fpu vme sse sse2 avx fma avx2 bmi2
processor\t: 1
model name\t: AMD EPYC 7B13
flags\t\t: fpu vme sse sse2 avx fma avx2 bmi2 avx512f
"""


def test_cpuinfo_gives_the_first_cpus_model_and_its_vector_flags():
    model, isa = cpu_model_and_flags(X86)
    assert model == "AMD EPYC 7B13"
    assert isa == ["avx2", "fma", "avx"]          # the first processor's, in ISA_FLAGS order
    # an arm64 /proc/cpuinfo names no model and lists 'Features'
    assert cpu_model_and_flags("processor\t: 0\nFeatures\t: fp asimd\n") == ("", [])
    assert cpu_model_and_flags("") == ("", [])


def test_machine_info_reports_the_installed_libraries_and_is_json():
    info = machine_info()
    assert info["packages"]["numpy"] == np.__version__
    assert info["packages"]["torch"].startswith("2.13.0")   # the pinned build
    assert info["cores"] >= 1 and info["load_average"] >= 0
    commit = info["commit"]
    assert commit is None or all(c in "0123456789abcdef" for c in commit.removesuffix("+dirty"))
    assert json.loads(json.dumps(info)) == info
