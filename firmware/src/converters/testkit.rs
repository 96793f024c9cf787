//! Helpers of the converters' tests: chip-select frames as `embedded-hal-mock`
//! expectations, and an SPI device that always fails.

use embedded_hal::spi::{ErrorKind, ErrorType, Operation, SpiDevice};
use embedded_hal_mock::eh1::spi::Transaction;

/// One chip-select frame that writes `bytes`.
pub fn write(bytes: &[u8]) -> Vec<Transaction<u8>> {
    framed(Transaction::write_vec(bytes.to_vec()))
}

/// One chip-select frame that reads `reply` (the master sends don't-care bytes).
pub fn read(reply: &[u8]) -> Vec<Transaction<u8>> {
    framed(Transaction::read_vec(reply.to_vec()))
}

/// One chip-select frame that sends `sent` while `reply` comes back.
pub fn transfer(sent: &[u8], reply: &[u8]) -> Vec<Transaction<u8>> {
    framed(Transaction::transfer(sent.to_vec(), reply.to_vec()))
}

/// `op` between chip select low and high.
fn framed(op: Transaction<u8>) -> Vec<Transaction<u8>> {
    vec![
        Transaction::transaction_start(),
        op,
        Transaction::transaction_end(),
    ]
}

/// An SPI device whose every transaction fails with its kind.
pub struct Broken(pub ErrorKind);

impl ErrorType for Broken {
    type Error = ErrorKind;
}

impl SpiDevice for Broken {
    fn transaction(&mut self, _: &mut [Operation<'_, u8>]) -> Result<(), ErrorKind> {
        Err(self.0)
    }
}
