"""Routes of a port's raw sensor registers (admin): the table, ``GET`` and ``PUT`` one."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Path
from fastapi.responses import JSONResponse

from elphel_camd.api.deps import READS, WRITES, PortPath, Service
from elphel_camd.api.errors import error_responses
from elphel_camd.api.models import RegisterEntry, RegisterValue, RegisterWrite
from elphel_camd.errors import ParameterRangeError
from elphel_camd.sensors import register_file
from elphel_camd.sensors.registers import BoundField, Register

router = APIRouter()

AddressPath = Annotated[
    str,
    Path(
        pattern=r"^(0[xX][0-9a-fA-F]{1,4}|[0-9]{1,5})$",
        description="register address, decimal or 0x hex",
    ),
]


def parse_address(text: str) -> int:
    try:
        return int(text, 0)
    except ValueError:
        raise ParameterRangeError("address", text, "a register address, e.g. 0x09 or 9") from None


def register_body(port: int, register: Register, value: int) -> dict[str, Any]:
    return {
        "port": port,
        "name": register.name,
        "address": register.address,
        "value": value,
        "access": str(register.access),
        "minimum": register.minimum,
        "maximum": register.limit,
        "unit": register.unit,
        "doc": register.doc,
        "fields": {b.field.name: b.get(value) for b in bound_fields(register)},
    }


def bound_fields(register: Register) -> list[BoundField]:
    return [BoundField(register, f) for f in register.fields]


def field_info(bound: BoundField) -> dict[str, Any]:
    f = bound.field
    return {"name": f.name, "msb": f.msb, "lsb": f.shift, "doc": f.doc}


@router.get(
    "/ports/{port}/registers",
    response_model=list[RegisterEntry],
    dependencies=READS,
    responses=error_responses(401, 404),
)
def list_registers(service: Service, port: PortPath) -> JSONResponse:
    """The sensor's register table: names, addresses, access, reset values, limits."""
    table = register_file(service.sensor(port)).table
    return JSONResponse(
        [
            {
                "name": r.name,
                "address": r.address,
                "access": str(r.access),
                "reset": r.reset,
                "minimum": r.minimum,
                "maximum": r.limit,
                "width": r.width,
                "unit": r.unit,
                "doc": r.doc,
                "fields": [field_info(b) for b in bound_fields(r)],
            }
            for r in table
        ]
    )


@router.get(
    "/ports/{port}/registers/{addr}",
    response_model=RegisterValue,
    dependencies=READS,
    responses=error_responses(401, 404, 409, 422, 503),
)
def get_register(service: Service, port: PortPath, addr: AddressPath) -> JSONResponse:
    """Read a raw sensor register now (address decimal or 0x hex)."""
    register, value = service.read_register(port, parse_address(addr))
    return JSONResponse(register_body(port, register, value))


@router.put(
    "/ports/{port}/registers/{addr}",
    response_model=RegisterValue,
    dependencies=WRITES,
    responses=error_responses(401, 404, 409, 413, 422, 503),
)
def put_register(
    service: Service, port: PortPath, addr: AddressPath, body: RegisterWrite
) -> JSONResponse:
    """Write a raw sensor register (admin), checked against the register table.

    The write bypasses the frame sequencer: the next change of a parameter that owns
    this register overwrites it.
    """
    register = service.write_register(port, parse_address(addr), body.value)
    return JSONResponse(register_body(port, register, body.value))
