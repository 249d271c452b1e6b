"""The reconstruction's train_log.csv: a resumed run keeps the rows up to its checkpoint."""

from trase.training_log import ProgressBar, TrainLog


def test_train_log_keeps_rows_up_to_the_resumed_iteration(tmp_path):
    path = tmp_path / "m" / "train_log.csv"
    log = TrainLog(path, 0)
    for it in (10, 20, 30):
        log.write(it, 0.5, 20.0, 100, 1.0, 2.0)
    log.close()
    assert path.read_text().splitlines()[1] == "10,0.500000,20.0000,100,1.00,2.00,0"
    TrainLog(path, 20).close()  # resumed from iteration 20: row 30 is gone
    assert path.read_text() == TrainLog.HEADER + "10,0.500000,20.0000,100,1.00,2.00,0\n20,0.500000,20.0000,100,1.00,2.00,0\n"
    TrainLog(path, 0).close()  # a fresh run starts a fresh log
    assert path.read_text() == TrainLog.HEADER


def test_disabled_progress_bar_does_nothing():
    bar = ProgressBar(False, 10, 0)
    bar.update(5, "loss 0.1")
    bar.close()
    assert bar.bar is None
