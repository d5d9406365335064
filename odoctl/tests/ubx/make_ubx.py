"""Writes a mixed u-blox log (UBX, NMEA, RTCM 3) with the independent `pyubx2` and `pyrtcm`
packages, and prints what a reader must find in it as JSON.

Usage: make_ubx.py OUT.ubx > expected.json

Epochs at 10 Hz across the end of GPS week 2305, each with NAV-PVT and some with
NAV-HPPOSLLH, NAV-RELPOSNED (moving and static base) and NAV-TIMEGPS; flags chosen so that
a reader going by fix type alone, or using a static base's bearing, would go wrong.
"""

import datetime
import json
import sys

from pyrtcm import calc_crc24q
from pyubx2 import GET, UBXMessage

WEEK = 2305
LEAP = 18
GPS_EPOCH = datetime.datetime(1980, 1, 6)


def utc_of(week, itow_ms):
    return GPS_EPOCH + datetime.timedelta(weeks=week, milliseconds=itow_ms - LEAP * 1000)


def pvt(week, itow, fix_ok, carr, diff, fix_type=3, valid_date=1, invalid=0, lat=49.2, lon=16.6, h_mm=300_000):
    t = utc_of(week, itow)
    return UBXMessage(
        "NAV", "NAV-PVT", GET, iTOW=itow, year=t.year, month=t.month, day=t.day, hour=t.hour,
        min=t.minute, second=t.second, nano=t.microsecond * 1000, validDate=valid_date,
        validTime=valid_date, fullyResolved=1, fixType=fix_type, gnssFixOk=fix_ok,
        diffSoln=diff, carrSoln=carr, numSV=24, lon=lon, lat=lat, height=h_mm,
        hMSL=h_mm - 45_000, hAcc=14, vAcc=21, invalidLlh=invalid,
    )


def rtcm3(msg_type, body):
    bits = msg_type << 4
    payload = bytes([bits >> 8, bits & 0xFF]) + body
    frame = bytes([0xD3, len(payload) >> 8, len(payload) & 0xFF]) + payload
    return frame + calc_crc24q(frame).to_bytes(3, "big")


def main():
    out = bytearray()
    expected = []
    lat0, lon0 = 49.2012345, 16.6012345
    itows = [604_799_800, 604_799_900, 0, 100, 200]
    for k, itow in enumerate(itows):
        week = WEEK if itow > 600_000_000 else WEEK + 1
        gps_time = week * 604_800 + itow / 1000
        lat = lat0 + k * 1e-6
        e = {"gps_time": gps_time, "lat": lat, "lon": lon0, "height": 300.0 + k, "heading": None,
             "hacc": 0.014, "vacc": 0.021}
        if k == 0:
            out += UBXMessage("NAV", "NAV-TIMEGPS", GET, iTOW=itow, week=week, leapS=LEAP,
                              towValid=1, weekValid=1, leapSValid=1).serialize()
            out += pvt(week, itow, 1, 2, 1, lat=lat, lon=lon0, h_mm=300_000 + 1000 * k).serialize()
            # The high-precision position replaces NAV-PVT's.
            out += UBXMessage("NAV", "NAV-HPPOSLLH", GET, version=0, iTOW=itow, lon=lon0, lat=lat,
                              height=300_000 + 1000 * k, hMSL=255_000, _HPlon=1.2e-8,
                              _HPlat=-3.4e-8, _HPheight=0.5, hAcc=8.1 + 1e-6,
                              vAcc=12.3 + 1e-6).serialize()
            e.update(lat=lat - 3.4e-8, lon=lon0 + 1.2e-8, height=300.0005, hacc=0.0081, vacc=0.0123)
            out += UBXMessage("NAV", "NAV-RELPOSNED", GET, version=1, iTOW=itow, relPosN=80,
                              # pyubx2 truncates value / scale: a hair above the exact value.
                              relPosLength=80, relPosHeading=123.25 + 1e-9, gnssFixOK=1,
                              relPosValid=1, relPosHeadingValid=1, isMoving=1, carrSoln=2).serialize()
            e["heading"] = 123.25
            e["fix"] = "RtkFixed"
            out += b"$GNGGA,235941.80,4912.07407,N,01636.07407,E,4,24,0.5,255.0,M,45.0,M,1.0,0000*"
            body = b"GNGGA,235941.80,4912.07407,N,01636.07407,E,4,24,0.5,255.0,M,45.0,M,1.0,0000"
            x = 0
            for b in body:
                x ^= b
            out += f"{x:02X}\r\n".encode()
        elif k == 1:
            out += pvt(week, itow, 1, 1, 1, lat=lat, lon=lon0, h_mm=300_000 + 1000 * k).serialize()
            # A static base: relPosHeading is the bearing from the base, not the heading.
            out += UBXMessage("NAV", "NAV-RELPOSNED", GET, version=1, iTOW=itow, relPosN=5000,
                              relPosHeading=10.0, gnssFixOK=1, relPosValid=1,
                              relPosHeadingValid=1, isMoving=0, carrSoln=1).serialize()
            out += rtcm3(1005, bytes(17))
            e["fix"] = "RtkFloat"
        elif k == 2:
            # A 3D fix the receiver flags not OK: no valid fix.
            out += pvt(week, itow, 0, 0, 0, lat=lat, lon=lon0, h_mm=300_000 + 1000 * k).serialize()
            out += UBXMessage("NAV", "NAV-CLOCK", GET, iTOW=itow, clkB=1, clkD=2).serialize()
            e["fix"] = "Invalid"
        elif k == 3:
            out += pvt(week, itow, 1, 2, 1, lat=lat, lon=lon0, h_mm=300_000 + 1000 * k).serialize()
            # Flagged invalid: NAV-PVT's position stays.
            out += UBXMessage("NAV", "NAV-HPPOSLLH", GET, version=0, iTOW=itow, lon=1.0, lat=1.0,
                              height=0, hMSL=0, hAcc=1, vAcc=1, invalidLlh=1).serialize()
            e["fix"] = "RtkFixed"
        else:
            # No valid date: the week comes from the previous epoch.
            out += pvt(week, itow, 1, 0, 1, valid_date=0, lat=lat, lon=lon0,
                       h_mm=300_000 + 1000 * k).serialize()
            out += UBXMessage("NAV", "NAV-RELPOSNED", GET, version=1, iTOW=itow, relPosHeading=45.0,
                              gnssFixOK=1, relPosValid=1, relPosHeadingValid=0, isMoving=1).serialize()
            e["fix"] = "Dgps"
        expected.append(e)
    # A frame with a bad checksum, then one cut off at the end of the file.
    bad = bytearray(pvt(WEEK + 1, 300, 1, 2, 1).serialize())
    bad[-1] ^= 0xFF
    out += bad
    out += pvt(WEEK + 1, 400, 1, 2, 1).serialize()[:50]
    with open(sys.argv[1], "wb") as f:
        f.write(out)
    json.dump({"epochs": expected, "corrupt": 2, "other": {"RTCM3 1005": 1, "NMEA GNGGA": 1,
               "NAV 0x22": 1}, "static_base": 1}, sys.stdout)


if __name__ == "__main__":
    main()
