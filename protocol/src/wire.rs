//! How an enum crosses the link: by the number written beside each variant,
//! never by its place in the declaration.
//!
//! * A fieldless enum (`wire_enum!`) is one byte, its `#[repr(u8)]`
//!   discriminant.
//! * An enum with fields (a [`Command`](crate::Command), a
//!   [`Reply`](crate::Reply), …) is its kind's byte — the discriminant of its
//!   fieldless kind enum, e.g. [`CommandKind`](crate::CommandKind) — followed by
//!   the variant's fields in order, each in postcard's encoding ([`Tagged`]).
//!
//! Structs stay serde-derived: postcard writes their fields in order, with no
//! number of their own. The golden-byte tests (`tests/golden.rs`) pin every
//! message's bytes.

use core::fmt;
use core::marker::PhantomData;

use serde::de::{self, SeqAccess, Visitor};
use serde::ser::SerializeTuple;
use serde::{Deserialize, Deserializer, Serializer};

/// Declares a fieldless enum that crosses the link as its `#[repr(u8)]`
/// discriminant: every variant's number written out, `ALL` (every variant, in
/// declaration order), `from_u8` (`None` for a number the enum does not have)
/// and serde impls that write and read that byte.
#[macro_export]
macro_rules! wire_enum {
    (
        $(#[$meta:meta])*
        pub enum $name:ident {
            $($(#[$vmeta:meta])* $variant:ident = $n:literal $(as $label:literal)?,)+
        }
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[repr(u8)]
        pub enum $name {
            $($(#[$vmeta])* $variant = $n,)+
        }

        impl $name {
            /// Every variant, in declaration order.
            pub const ALL: &'static [Self] = &[$(Self::$variant,)+];

            /// The variant whose wire number is `byte`.
            pub const fn from_u8(byte: u8) -> Option<Self> {
                match byte {
                    $($n => Some(Self::$variant),)+
                    _ => None,
                }
            }

            /// Its wire number (the discriminant).
            pub const fn to_u8(self) -> u8 {
                self as u8
            }

            /// Its name in a human-readable format (JSON, the settings tree),
            /// where the declaration gives one (`Variant = n as "name"`).
            pub const fn label(self) -> Option<&'static str> {
                match self {
                    $(Self::$variant => $crate::wire::label(&[$($label)?]),)+
                }
            }

            /// The variant named `name` (see [`Self::label`]).
            pub fn from_label(name: &str) -> Option<Self> {
                Self::ALL.iter().copied().find(|v| v.label() == Some(name))
            }
        }

        impl $crate::serde::Serialize for $name {
            fn serialize<S: $crate::serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                match self.label() {
                    Some(name) if s.is_human_readable() => s.serialize_str(name),
                    _ => s.serialize_u8(self.to_u8()),
                }
            }
        }

        impl<'de> $crate::serde::Deserialize<'de> for $name {
            fn deserialize<D: $crate::serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                if d.is_human_readable() && Self::ALL.iter().any(|v| v.label().is_some()) {
                    return d.deserialize_str($crate::wire::LabelVisitor::<Self>::new(
                        stringify!($name),
                        Self::from_label,
                    ));
                }
                let byte = <u8 as $crate::serde::Deserialize>::deserialize(d)?;
                Self::from_u8(byte).ok_or_else(|| {
                    <D::Error as $crate::serde::de::Error>::invalid_value(
                        $crate::serde::de::Unexpected::Unsigned(byte.into()),
                        &stringify!($name),
                    )
                })
            }
        }
    };
}

/// The label a `wire_enum!` variant declares (`as "name"`), if any.
#[doc(hidden)]
pub const fn label(declared: &[&'static str]) -> Option<&'static str> {
    match declared {
        [name] => Some(name),
        _ => None,
    }
}

/// Reads a labelled `wire_enum!` from its name (a human-readable format).
#[doc(hidden)]
pub struct LabelVisitor<T> {
    name: &'static str,
    parse: fn(&str) -> Option<T>,
}

impl<T> LabelVisitor<T> {
    /// For the enum `name`, its variants found by `parse`.
    pub const fn new(name: &'static str, parse: fn(&str) -> Option<T>) -> Self {
        Self { name, parse }
    }
}

impl<'de, T> Visitor<'de> for LabelVisitor<T> {
    type Value = T;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "the name of a {}", self.name)
    }

    fn visit_str<E: de::Error>(self, v: &str) -> Result<T, E> {
        (self.parse)(v).ok_or_else(|| E::invalid_value(de::Unexpected::Str(v), &self))
    }
}

/// Most fields a tagged variant has, its kind byte included (a bound for the
/// decoder; postcard reads only those the variant asks for).
const MOST_FIELDS: usize = 16;

/// An enum with fields on the wire: its kind byte, then its variant's fields.
pub trait Tagged<'de>: Sized {
    /// Its name, for errors.
    const NAME: &'static str;
    /// The kind byte of this value.
    fn kind(&self) -> u8;
    /// Writes the variant's fields (after the kind byte).
    fn write<T: SerializeTuple>(&self, t: &mut T) -> Result<(), T::Error>;
    /// Reads the fields of the variant of kind `kind`; `None` if there is no such
    /// kind.
    fn read<A: SeqAccess<'de>>(kind: u8, a: &mut A) -> Result<Option<Self>, A::Error>;
}

/// The next field of a tagged variant.
pub fn field<'de, T: Deserialize<'de>, A: SeqAccess<'de>>(a: &mut A) -> Result<T, A::Error> {
    a.next_element()?
        .ok_or_else(|| de::Error::invalid_length(MOST_FIELDS, &"a field of the message"))
}

/// Writes each expression as the next field of a tagged variant.
#[macro_export]
#[doc(hidden)]
macro_rules! put {
    ($t:expr; $($field:expr),* $(,)?) => {{
        $($crate::serde::ser::SerializeTuple::serialize_element($t, $field)?;)*
    }};
}

/// Serializes a tagged value: its kind byte, then its fields.
pub fn serialize<'de, V: Tagged<'de>, S: Serializer>(v: &V, s: S) -> Result<S::Ok, S::Error> {
    let mut t = s.serialize_tuple(MOST_FIELDS)?;
    t.serialize_element(&v.kind())?;
    v.write(&mut t)?;
    t.end()
}

/// Deserializes a tagged value; an unknown kind is an invalid value.
pub fn deserialize<'de, V: Tagged<'de>, D: Deserializer<'de>>(d: D) -> Result<V, D::Error> {
    d.deserialize_tuple(MOST_FIELDS, TaggedVisitor(PhantomData))
}

struct TaggedVisitor<V>(PhantomData<V>);

impl<'de, V: Tagged<'de>> Visitor<'de> for TaggedVisitor<V> {
    type Value = V;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(V::NAME)
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut a: A) -> Result<V, A::Error> {
        let kind: u8 = field(&mut a)?;
        V::read(kind, &mut a)?.ok_or_else(|| {
            de::Error::invalid_value(de::Unexpected::Unsigned(kind.into()), &V::NAME)
        })
    }
}

/// serde impls for a type that implements [`Tagged`]; `Name<'a>` for a type
/// with borrowed fields (it deserializes borrowing from the frame).
#[macro_export]
#[doc(hidden)]
macro_rules! tagged_serde {
    ($name:ident<$l:lifetime>) => {
        impl<$l> $crate::serde::Serialize for $name<$l> {
            fn serialize<S: $crate::serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                $crate::wire::serialize(self, s)
            }
        }

        impl<'de> $crate::serde::Deserialize<'de> for $name<'de> {
            fn deserialize<D: $crate::serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                $crate::wire::deserialize(d)
            }
        }
    };
    ($name:ident) => {
        impl $crate::serde::Serialize for $name {
            fn serialize<S: $crate::serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                $crate::wire::serialize(self, s)
            }
        }

        impl<'de> $crate::serde::Deserialize<'de> for $name {
            fn deserialize<D: $crate::serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                $crate::wire::deserialize(d)
            }
        }
    };
}
