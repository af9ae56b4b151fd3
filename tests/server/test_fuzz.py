"""A schema fuzzer (schemathesis) over every operation of openapi.json, against a real server of
its own (the data it makes stays out of the other tests' server): bounded (a few generated
requests per operation, derandomized so every run sends the same ones, a time budget), and no
answer may be a 5xx (schemathesis's not_a_server_error check)."""
import time

import hypothesis
import hypothesis.errors
import schemathesis
from schemathesis import GenerationMode
from schemathesis.checks import not_a_server_error

from helpers import GlintServer

BUDGET_S = 90.0                   # for all operations; those after it are left out (and counted)
EXAMPLES = 12                     # generated requests per operation and mode (fewer when it has few inputs)


def test_no_operation_answers_a_server_error(tmp_path):
    srv = GlintServer(tmp_path / "data", workers=1)
    try:
        schema = schemathesis.openapi.from_url(srv.base + "/openapi.json")
        failures, sent, skipped = [], [0], []
        t0 = time.monotonic()
        for result in schema.get_all_operations():
            op = result.ok()
            if time.monotonic() - t0 > BUDGET_S:
                skipped.append(op.label)
                continue

            # requests that fit the schema, and requests that break it (out-of-range integers,
            # wrong types, missing fields): either may be refused, neither may be a server error
            for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):
                @hypothesis.settings(max_examples=EXAMPLES, derandomize=True, deadline=None, database=None,
                                     suppress_health_check=list(hypothesis.HealthCheck), phases=[
                                         hypothesis.Phase.explicit, hypothesis.Phase.generate])
                @hypothesis.given(case=op.as_strategy(generation_mode=mode))
                def run(case):
                    sent[0] += 1
                    case.call_and_validate(base_url=srv.base, checks=[not_a_server_error], timeout=60)
                try:
                    run()
                except hypothesis.errors.Unsatisfiable:
                    pass                                 # no input to break (no parameters, or free strings)
                except Exception as e:               # the failing case, minimised by hypothesis
                    failures.append(f"{op.label} ({mode.value}): {str(e)[:1500]}")
        assert not failures, f"{len(failures)} operation(s) answered 5xx:\n" + "\n\n".join(failures)
        assert sent[0] >= 50, sent
        assert len(skipped) <= 3, f"the {BUDGET_S:.0f} s budget left out {skipped}"
        print(f"{sent[0]} requests over the operations in {time.monotonic() - t0:.0f} s; left out: {skipped}")
    finally:
        srv.stop()
