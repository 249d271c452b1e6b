"""What `trase-bench run` prints beside the scores."""

from benchmark.commands.run import stopped_stages


def test_the_run_line_says_where_each_stage_stopped():
    rec = {"stages": {"geometry": {"info": {"test_psnr": 27.0}},
                      "features": {"info": {"stopping": {"stopped_at": 1000, "cap": 3000}}}}}
    assert stopped_stages(rec) == " [stop when converged: features stopped at 1000 of 3000]"
    rec["stages"]["geometry"]["info"]["stopping"] = {"stopped_at": None, "cap": 4000}
    assert stopped_stages(rec) == " [stop when converged: geometry ran all 4000, features stopped at 1000 of 3000]"
    assert stopped_stages({"stages": {"features": {"info": None}}}) == ""
