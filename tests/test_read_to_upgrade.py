"""dockingrl.io.read_to_upgrade: the one reader of the upgrade commands of checkpoints and
filter parameters (and policies): current format, an older one, any other."""

import pytest

from dockingrl.io import ArtifactError, read_to_upgrade, save_artifact
from dockingrl.training.checkpointing import upgrade_state
from dockingrl.transforms.params import upgrade_filter_params

FORMAT, OLD = "dockingrl.thing/3", ("dockingrl.thing/2", "dockingrl.thing/1")


@pytest.mark.parametrize("found", OLD)
def test_an_older_format_gives_its_payload(tmp_path, found):
    save_artifact(tmp_path / "a.pt", {"format": found, "x": 1})
    assert read_to_upgrade(tmp_path / "a.pt", "thing", FORMAT, OLD) == {"format": found, "x": 1}


def test_the_current_format_gives_none(tmp_path):
    save_artifact(tmp_path / "a.pt", {"format": FORMAT})
    assert read_to_upgrade(tmp_path / "a.pt", "thing", FORMAT, OLD) is None


@pytest.mark.parametrize("upgrade", [None, upgrade_state, upgrade_filter_params])
def test_another_format_is_refused_in_one_line_naming_file_and_format(tmp_path, upgrade):
    path = tmp_path / "a.pt"
    save_artifact(path, {"format": "dockingrl.policy/2"})
    with pytest.raises(ArtifactError) as err:
        if upgrade is None:
            read_to_upgrade(path, "thing", FORMAT, OLD)
        else:
            upgrade(path)
    message = str(err.value)
    assert message.startswith(f"{path}: not a ") and "\n" not in message
    assert message.endswith(": its format is 'dockingrl.policy/2'")
