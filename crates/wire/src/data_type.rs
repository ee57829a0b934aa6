//! CiA data types (ETG.1000.6 table 64; BYTE, WORD, DWORD and the bit strings from ETG.1020
//! table 98): the codes SDO Information's entry descriptions and the SII's PDO entries carry.

/// BOOLEAN.
pub const BOOL: u16 = 0x0001;
/// INTEGER8.
pub const INT8: u16 = 0x0002;
/// INTEGER16.
pub const INT16: u16 = 0x0003;
/// INTEGER32.
pub const INT32: u16 = 0x0004;
/// UNSIGNED8.
pub const UINT8: u16 = 0x0005;
/// UNSIGNED16.
pub const UINT16: u16 = 0x0006;
/// UNSIGNED32.
pub const UINT32: u16 = 0x0007;
/// REAL32.
pub const REAL32: u16 = 0x0008;
/// VISIBLE_STRING.
pub const VISIBLE_STRING: u16 = 0x0009;
/// OCTET_STRING.
pub const OCTET_STRING: u16 = 0x000a;
/// UNICODE_STRING.
pub const UNICODE_STRING: u16 = 0x000b;
/// TIME_OF_DAY.
pub const TIME_OF_DAY: u16 = 0x000c;
/// TIME_DIFFERENCE.
pub const TIME_DIFFERENCE: u16 = 0x000d;
/// DOMAIN.
pub const DOMAIN: u16 = 0x000f;
/// INTEGER24.
pub const INT24: u16 = 0x0010;
/// REAL64.
pub const REAL64: u16 = 0x0011;
/// INTEGER40.
pub const INT40: u16 = 0x0012;
/// INTEGER48.
pub const INT48: u16 = 0x0013;
/// INTEGER56.
pub const INT56: u16 = 0x0014;
/// INTEGER64.
pub const INT64: u16 = 0x0015;
/// UNSIGNED24.
pub const UINT24: u16 = 0x0016;
/// UNSIGNED40.
pub const UINT40: u16 = 0x0018;
/// UNSIGNED48.
pub const UINT48: u16 = 0x0019;
/// UNSIGNED56.
pub const UINT56: u16 = 0x001a;
/// UNSIGNED64.
pub const UINT64: u16 = 0x001b;
/// BYTE.
pub const BYTE: u16 = 0x001e;
/// WORD.
pub const WORD: u16 = 0x001f;
/// DWORD.
pub const DWORD: u16 = 0x0020;
/// BITARR8.
pub const BITARR8: u16 = 0x002d;
/// BITARR16.
pub const BITARR16: u16 = 0x002e;
/// BITARR32.
pub const BITARR32: u16 = 0x002f;
/// BIT1; BIT2 to BIT8 follow (0x0031-0x0037).
pub const BIT1: u16 = 0x0030;
