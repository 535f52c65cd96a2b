"""A bus for transcript tests: it expects an exact sequence of I2C transactions."""

I2C_M_RD = 1


class ScriptedBus:
    """Expects an exact sequence of transactions; each read answers with scripted bytes.

    A transaction is a list of ``("w", addr, bytes)`` / ``("r", addr, bytes-to-return)``
    messages, or an int errno that fails the whole transaction.
    """

    def __init__(self, script):
        self.script = list(script)

    def i2c_rdwr(self, *msgs):
        assert self.script, f"unexpected transaction {[bytes(m) for m in msgs]}"
        expected = self.script.pop(0)
        if isinstance(expected, int):
            raise OSError(expected, "scripted failure")
        assert len(msgs) == len(expected), f"{msgs} != {expected}"
        for msg, (kind, addr, data) in zip(msgs, expected, strict=True):
            assert msg.addr == addr
            if kind == "w":
                assert not msg.flags & I2C_M_RD
                assert bytes(msg) == data, f"{bytes(msg).hex()} != {data.hex()}"
            else:
                assert msg.flags & I2C_M_RD
                assert msg.len == len(data)
                for i, b in enumerate(data):
                    msg.buf[i] = bytes([b])

    def done(self):
        assert not self.script, f"transactions left unconsumed: {self.script}"
