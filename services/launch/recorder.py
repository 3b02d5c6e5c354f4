"""A run's recording, made where the samples already are: each service keeps what it publishes in a
journal (``services/runtime/journal.py``), and ``up`` the services' status replies and the run's
summary in its own; at the end of the run :class:`RunRecorder` makes ``run.mcap`` of them
(``services/recording/record.py``)."""

from __future__ import annotations

import shutil
from collections.abc import Sequence
from pathlib import Path

import zenoh

from schemas.keys import Keys
from services.config import Config, ConfigError, RecordConfig
from services.launch.children import say
from services.recording.record import RunRecording, StatusPoll, write_run_recording
from services.recording.report import rotated_line
from services.runtime.journal import Journal, journal_path
from services.service import Journaling, journal_limits

JOURNALS_DIRECTORY = "journals"
"""Where the services keep what they publish while the run lasts (made into ``run.mcap`` at its end)."""


class RunRecorder:
    """The run's recording, made where the samples already are (services/recording/record.py): each service
    keeps what it publishes in a journal in ``<report dir>/journals/``, and this, in ``up``'s own
    journal, the services' status replies and the run's summary. :meth:`write` makes ``run.mcap``
    of them once every service has stopped (and closed its journal). ``record`` bounds it all:
    the ``journals`` journals of the run (the services' and this one) share ``record.max_size``
    (equally, or, keeping the newest, by what each writes: services/runtime/journal.py)."""

    def __init__(self, report_dir: Path, record: RecordConfig, journals: int) -> None:
        self.record = record
        self.directory = report_dir / JOURNALS_DIRECTORY
        self._made = [
            directory for directory in (self.directory, report_dir, *report_dir.parents) if not directory.exists()
        ]
        """The directories this run makes, deepest first: a run that never starts removes them again."""
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            self.journal = Journal(journal_path(self.directory, "up"), journal_limits(record, journals))
        except OSError as error:
            raise ConfigError(f"--report {report_dir}: {error.strerror}") from None
        self.journals = journals
        self._statuses: StatusPoll | None = None

    def journaling(self, directory: Path | None = None) -> Journaling:
        """Where a service keeps its journal: ``directory`` (a fleet robot's own), else here."""
        return Journaling(directory or self.directory, self.journals)

    def watch(self, session: zenoh.Session, keys: Keys) -> None:
        """Record the services' status from now on, at each :meth:`during`."""
        self._statuses = StatusPoll(session, keys, self.journal.write)

    def during(self) -> None:
        if self._statuses is not None:
            self._statuses.poll()

    def last_statuses(self) -> None:
        """The services' status as the run ends, before they stop (:meth:`StatusPoll.last`)."""
        if self._statuses is not None:
            self._statuses.last()

    def write(self, path: Path, config: Config, fleet: Sequence[Config] = ()) -> RunRecording:
        """``run.mcap`` with the scene of ``config``'s robot, or of every robot of ``fleet``."""
        self._statuses = None
        self.journal.close()
        say(f"writing {path} from what the services published")
        written = write_run_recording(self.directory, path, config, fleet, self.record)
        for journal in written.cut_short:
            say(f"{journal.name} was cut short (its service was killed): {path} lacks its last samples")
        if written.stopped is not None:
            say(f"the recording stopped before the run did ({written.stopped['reason']}); the robot went on")
        if written.rotated is not None:
            say(rotated_line(written.rotated))
        if len(written.parts) > 1:
            say(f"the recording is split into {len(written.parts)} files: {', '.join(p.name for p in written.parts)}")
        shutil.rmtree(self.directory)
        return written

    def finish(self, started: bool, path: Path, config: Config, fleet: Sequence[Config] = ()) -> None:
        """At the run's end, however it ended: ``run.mcap`` of what was published (:meth:`write`),
        or, for a run that never started (the sim did not), nothing left behind (:meth:`discard`)."""
        if started:
            self.write(path, config, fleet)
        else:
            self.discard()
            say("the run never started (the sim did not): nothing recorded")

    def discard(self) -> None:
        """A run that never started (the sim never did): no recording of nothing, and the
        directories this run made are removed unless something else was put in them."""
        self._statuses = None
        self.journal.close()
        shutil.rmtree(self.directory)
        for directory in self._made[1:]:
            try:
                directory.rmdir()
            except OSError:  # not empty: the run's secrets, or someone else's files
                break
