"""Function codes (device 1 = CNC unless marked PMC), as others' protocol analysis found them."""

from __future__ import annotations

START = 0x01  # cnc_start: cycle start (series that allow it; see docs/focas.md)
SELECT_NUMBER = 0x03  # cnc_search: select program O<a1>
DELETE_NUMBER = 0x05  # cnc_delete: delete program O<a1>
PROGRAM_DIR = 0x06  # cnc_rdprogdir: O-number programs from a1
PARAMETER = 0x0E  # cnc_rdparam: a1..a2, axis a3
MACRO_READ = 0x15  # cnc_rdmacro(r): a1..a2, 8-byte numbers
MACRO_WRITE = 0x16  # cnc_wrmacro(r): a1..a2, data: 8-byte numbers
SYSINFO = 0x18
STATINFO = 0x19
ALARM_STATUS = 0x1A  # cnc_alarm: a bit per alarm type
PROGRAM_NUMBER = 0x1C  # cnc_rdprgnum: running, main
SEQUENCE_NUMBER = 0x1D  # cnc_rdseqnum
EXECUTING_BLOCK = 0x20  # cnc_rdexecprog: a1 characters
ALARM_MESSAGES = 0x23  # cnc_rdalmmsg: type a1 (-1 all), a2 entries, a3 2 (with text), a4 text length
ACTUAL_FEED = 0x24  # cnc_actf
ACTUAL_SPINDLE = 0x25  # cnc_acts
POSITION = 0x26  # cnc_rdposition: type a1, axis a2 (-1 all)
DIAGNOSIS = 0x30  # cnc_diagnoss: a1..a2, axis a3
AXIS_NAMES = 0x89  # cnc_rdaxisname
SPINDLE_NAMES = 0x8A  # cnc_rdspdlname
MACRO_READ_DOUBLE = 0xA7  # pyfanuc's notes: read macro as double
MACRO_WRITE_DOUBLE = 0xA8  # pyfocas: write one macro, data: an IEEE double
CURRENT_FOLDER = 0xB0  # cnc_rdpdf_curdir (30i): a1 1 foreground, 2 background
READ_FOLDER = 0xB3  # cnc_rdpdf_alldir (30i): from a1, a2 entries, a3 type, a4 size; data: the folder
FOLDER_COUNT = 0xB4  # cnc_rdpdf_subdirn (30i): data: the folder
DELETE_FILE = 0xB6  # cnc_pdf_del (30i): data: the file's full name
SELECT_FILE = 0xBA  # cnc_pdf_slctmain (30i): data: the file's full name
PROGRAM_NAME = 0xCF  # cnc_exeprgname: O-number and name of the running program

PMC_READ = 0x8001  # device 2: a1..a2 (byte addresses), area a3, type a4 (0 byte, 1 word, 2 long)
PMC_WRITE = 0x8002  # device 2: as the read, data: the values

#: cnc_rdposition's a1 for each kind of position.
POSITION_TYPES = {"machine": 1, "absolute": 4, "relative": 6, "distance": 7}

#: PMC areas and their codes (pmc_rdpmcrng's adr_type).
PMC_AREAS = {"G": 0, "F": 1, "Y": 2, "X": 3, "A": 4, "R": 5, "T": 6, "K": 7, "C": 8, "D": 9, "M": 10,
             "N": 11, "E": 12, "Z": 13}  # fmt: skip
PMC_BYTE, PMC_WORD, PMC_LONG = 0, 1, 2
PMC_TYPE_SIZE = {PMC_BYTE: 1, PMC_WORD: 2, PMC_LONG: 4}
