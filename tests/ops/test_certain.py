"""The one re-read-until-certain loop (ops/certain.py): what it reads again, how often, and
what it says stays in doubt. A stand-in client whose ledger names the suspects."""

from tmclsh.ops.certain import CONFIRM_ROUNDS, read_until_certain


class Ledger:
    """``in_doubt`` as the client's: the answers among ``answered`` that are suspects."""

    def __init__(self, doubtful_reads):
        self.replies = 0
        self.doubtful_reads = doubtful_reads  # key -> how many of its reads come in doubt
        self.suspects: set[int] = set()
        self.confirms: list[bool] = []

    def read(self, key):
        self.replies += 1
        if self.doubtful_reads.get(key, 0) > 0:
            self.doubtful_reads[key] -= 1
            self.suspects.add(self.replies)
        return self.replies

    def in_doubt(self, answered, *, confirm=True):
        self.confirms.append(confirm)
        return {k for seq, k in answered.items() if seq in self.suspects}


def reader(client, keys, log):
    def read(doubt):
        todo = keys if doubt is None else sorted(doubt)
        log.append(list(todo))
        return {client.read(k): k for k in todo}
    return read


def test_only_the_doubtful_are_read_again_and_their_new_answer_counts():
    client, log = Ledger({"b": 1}), []
    found = read_until_certain(client, reader(client, ["a", "b", "c"], log))
    assert log == [["a", "b", "c"], ["b"]]
    assert found.doubt == set() and found.again == 1 and found.accepted
    assert sorted(found.answered.values()) == ["a", "b", "c"]
    assert len(found.taken) == 4  # the replaced answer too (for Doubts.settle)


def test_what_stays_in_doubt_after_the_bound_is_returned_not_raised():
    client, log = Ledger({"b": 99}), []
    found = read_until_certain(client, reader(client, ["a", "b"], log))
    assert log == [["a", "b"]] + [["b"]] * CONFIRM_ROUNDS
    assert found.doubt == {"b"} and found.again == CONFIRM_ROUNDS and not found.accepted


def test_no_rounds_again_marks_at_once_and_first_confirm_is_the_callers():
    client, log = Ledger({"a": 1}), []
    found = read_until_certain(client, reader(client, ["a"], log), again=0, confirm=False)
    assert log == [["a"]] and found.doubt == {"a"} and client.confirms == [False]


def test_reads_already_made_are_judged_without_reading_them_again():
    client, log = Ledger({}), []
    first = {client.read("a"): "a"}
    found = read_until_certain(client, reader(client, ["a"], log), first=first)
    assert log == [] and found.doubt == set() and found.answered == first


def test_accept_can_ask_for_a_certain_reading_twice():
    client, log = Ledger({}), []
    rounds = []
    found = read_until_certain(client, reader(client, ["a"], log), again=1,
                               accept=lambda doubt: (rounds.append(doubt), len(rounds) > 1)[1])
    assert log == [["a"], ["a"]] and found.accepted and found.again == 1
