//! The serialised settings (the payload of a flash record, `docs/PROTOCOL.md` section 5),
//! derived from the key table: each key at its [`RecordField`] offset in its [`Kind`]'s
//! little-endian encoding (byte 99, reserved and 0 before version 5, holds `output`).

use super::keys::{Kind, RecordField, Value, KEY_TABLE};
use super::{Key, SettingError, Settings};

/// Version of the serialised settings layout ([`Settings::to_bytes`]). Version 2 appended
/// `max_wheel_speed` to version 1, version 3 the geometry's standard errors and correlations
/// (`left_diameter_se`.. `right_track_correlation`) and `kappa_diff`, version 4
/// `kappa_diff_corr`, version 5 `output` (in the reserved byte 99), `mavlink_sysid` and
/// `mavlink_compid`, version 6 `gnss_baud`; [`Settings::from_bytes_version`] reads all six.
pub const SETTINGS_FORMAT_VERSION: u16 = 6;

/// Length of the payload of format `version`: the end of its last key, bytes.
pub const fn serialized_len(version: u16) -> usize {
    let mut len = 0;
    let mut i = 0;
    while i < KEY_TABLE.len() {
        let k = &KEY_TABLE[i];
        let end = k.record.offset as usize + k.kind.record_size();
        if k.record.since <= version && end > len {
            len = end;
        }
        i += 1;
    }
    len
}

/// True when no two keys of the table share a byte of the record.
const fn no_overlap() -> bool {
    let mut i = 0;
    while i < KEY_TABLE.len() {
        let mut j = i + 1;
        while j < KEY_TABLE.len() {
            let (a, b) = (&KEY_TABLE[i], &KEY_TABLE[j]);
            let (a0, b0) = (a.record.offset as usize, b.record.offset as usize);
            if a0 < b0 + b.kind.record_size() && b0 < a0 + a.kind.record_size() {
                return false;
            }
            j += 1;
        }
        i += 1;
    }
    true
}

const _: () = assert!(no_overlap(), "two keys share bytes of the settings record");

impl Settings {
    /// Length of the serialised form of format version [`SETTINGS_FORMAT_VERSION`] (6),
    /// bytes: 160 (from the key table).
    pub const SERIALIZED_LEN: usize = serialized_len(SETTINGS_FORMAT_VERSION);

    /// Length of the serialised form of format version 1, bytes: 112, the version 2 layout
    /// without its last field, `max_wheel_speed`.
    pub const SERIALIZED_LEN_V1: usize = serialized_len(1);

    /// Length of the serialised form of format version 2, bytes: 116, the version 3 layout
    /// without the geometry's standard errors and correlations and `kappa_diff`.
    pub const SERIALIZED_LEN_V2: usize = serialized_len(2);

    /// Length of the serialised form of format version 4, bytes: 148, the version 5 layout
    /// without `mavlink_sysid` and `mavlink_compid` (and 0, `frames`, in byte 99).
    pub const SERIALIZED_LEN_V4: usize = serialized_len(4);

    /// Length of the serialised form of format version 5, bytes: 156, the version 6 layout
    /// without `gnss_baud`.
    pub const SERIALIZED_LEN_V5: usize = serialized_len(5);

    /// Length of the serialised form of format version 3, bytes: 144, the version 4 layout
    /// without `kappa_diff_corr`.
    pub const SERIALIZED_LEN_V3: usize = serialized_len(3);

    /// Serialises into the fixed little-endian layout of format version
    /// [`SETTINGS_FORMAT_VERSION`] (documented in `docs/PROTOCOL.md`).
    pub fn to_bytes(&self) -> [u8; Self::SERIALIZED_LEN] {
        let mut out = [0u8; Self::SERIALIZED_LEN];
        for key in Key::ALL {
            let info = key.info();
            let mut word = [0u8; 8];
            let bytes: &[u8] = match (self.get(key), info.kind) {
                (Value::F64(v), _) => {
                    word = v.to_le_bytes();
                    &word
                }
                (Value::F32(v), _) => {
                    word[..4].copy_from_slice(&v.to_le_bytes());
                    &word[..4]
                }
                (Value::U32(v), _) => {
                    word[..4].copy_from_slice(&v.to_le_bytes());
                    &word[..4]
                }
                (Value::Word(w), Kind::Word(words)) => {
                    word[0] = words.iter().position(|x| *x == w).unwrap_or_default() as u8;
                    &word[..1]
                }
                (Value::Word(_), _) => &[],
            };
            // The table's offsets fit the layout (checked at compile time above).
            if let Some(dst) = field_mut(&mut out, info.record, bytes.len()) {
                dst.copy_from_slice(bytes);
            }
        }
        out
    }

    /// Parses the serialised form of the current format version ([`SETTINGS_FORMAT_VERSION`],
    /// at least [`Self::SERIALIZED_LEN`] bytes; extra bytes are ignored) and validates it.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, SettingError> {
        Self::from_bytes_version(SETTINGS_FORMAT_VERSION, bytes)
    }

    /// Parses the serialised form of format `version` and validates it: version 6
    /// ([`Self::SERIALIZED_LEN`] bytes), 5 ([`Self::SERIALIZED_LEN_V5`] bytes, before
    /// `gnss_baud`), 4 ([`Self::SERIALIZED_LEN_V4`] bytes, before the
    /// MAVLink keys), 3 ([`Self::SERIALIZED_LEN_V3`] bytes, before
    /// `kappa_diff_corr`), 2 ([`Self::SERIALIZED_LEN_V2`] bytes, before the geometry's
    /// standard errors) or 1 ([`Self::SERIALIZED_LEN_V1`] bytes, before `max_wheel_speed`); a
    /// key newer than the record takes its default. Too few bytes, a bad code, an unknown
    /// version or settings that do not validate (including under rules added since the
    /// record was written) are errors.
    pub fn from_bytes_version(version: u16, bytes: &[u8]) -> Result<Self, SettingError> {
        if !(1..=SETTINGS_FORMAT_VERSION).contains(&version) {
            return Err(SettingError::UnknownFormatVersion(version));
        }
        // Computed at compile time: the table itself stays out of the firmware's flash.
        const LEN: [usize; SETTINGS_FORMAT_VERSION as usize + 1] = {
            let mut len = [0; SETTINGS_FORMAT_VERSION as usize + 1];
            let mut v = 1;
            while v < len.len() {
                len[v] = serialized_len(v as u16);
                v += 1;
            }
            len
        };
        if bytes.len() < LEN.get(version as usize).copied().unwrap_or(usize::MAX) {
            return Err(SettingError::BadRecord);
        }
        let mut s = Self::DEFAULT;
        for key in Key::ALL {
            let info = key.info();
            if info.record.since > version {
                continue;
            }
            let at = info.record.offset as usize;
            let value = match info.kind {
                Kind::F64 { .. } => read::<8>(bytes, at).map(|b| Value::F64(f64::from_le_bytes(b))),
                Kind::F32 { .. } => read::<4>(bytes, at).map(|b| Value::F32(f32::from_le_bytes(b))),
                Kind::U32 { .. } | Kind::U32Set(_) => {
                    read::<4>(bytes, at).map(|b| Value::U32(u32::from_le_bytes(b)))
                }
                Kind::Word(words) => bytes
                    .get(at)
                    .and_then(|code| words.get(*code as usize))
                    .map(|w| Value::Word(w)),
            };
            value
                .and_then(|v| s.put(key, v))
                .ok_or(SettingError::BadRecord)?;
        }
        s.validate()?;
        Ok(s)
    }
}

fn field_mut(out: &mut [u8], field: RecordField, len: usize) -> Option<&mut [u8]> {
    let at = field.offset as usize;
    out.get_mut(at..at + len)
}

fn read<const N: usize>(bytes: &[u8], at: usize) -> Option<[u8; N]> {
    bytes.get(at..at + N)?.try_into().ok()
}
