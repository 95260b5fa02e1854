//! `m2smap-defmt-decode ELF < stream`: decodes the firmware's defmt stream (rzcobs frames, as `defmt-semihosting`
//! writes them to semihosting stdout) with the format strings in the ELF's `.defmt` section and prints one line
//! per log frame: the message alone for `defmt::println!` (the lines `make firmware` compares), `LEVEL message`
//! for `defmt::error!` and the other levels. Exits with status 2 if any frame was malformed (bytes in the stream
//! that are not defmt frames), so a corrupted log cannot pass as a clean one.
use std::io::{Read, Write};
use std::process::ExitCode;

use defmt_decoder::{DecodeError, Table};

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().collect();
    let [_, elf_path] = args.as_slice() else {
        eprintln!("usage: m2smap-defmt-decode FIRMWARE.elf < defmt-stream");
        return ExitCode::from(1);
    };
    let elf = match std::fs::read(elf_path) {
        Ok(b) => b,
        Err(e) => {
            eprintln!("m2smap-defmt-decode: cannot read {elf_path}: {e}");
            return ExitCode::from(1);
        }
    };
    let table = match Table::parse(&elf) {
        Ok(Some(t)) => t,
        Ok(None) => {
            eprintln!("m2smap-defmt-decode: {elf_path} has no .defmt section");
            return ExitCode::from(1);
        }
        Err(e) => {
            eprintln!("m2smap-defmt-decode: {elf_path}: {e}");
            return ExitCode::from(1);
        }
    };
    let mut decoder = table.new_stream_decoder();
    let stdin = std::io::stdin();
    let mut input = stdin.lock();
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    let mut buf = [0u8; 4096];
    let mut malformed = 0usize;
    loop {
        // Read as the bytes arrive, so the lines show while QEMU runs.
        let n = match input.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => {
                eprintln!("m2smap-defmt-decode: reading stdin: {e}");
                return ExitCode::from(1);
            }
        };
        decoder.received(&buf[..n]);
        loop {
            match decoder.decode() {
                Ok(frame) => {
                    let line = match frame.level() {
                        None => format!("{}", frame.display_message()),
                        Some(level) => format!("{} {}", level.as_str().to_uppercase(), frame.display_message()),
                    };
                    if writeln!(out, "{line}").and_then(|_| out.flush()).is_err() {
                        return ExitCode::from(1);
                    }
                }
                Err(DecodeError::UnexpectedEof) => break,
                Err(DecodeError::Malformed) => malformed += 1,
            }
        }
    }
    if malformed > 0 {
        eprintln!("m2smap-defmt-decode: {malformed} malformed defmt frame(s) skipped");
        return ExitCode::from(2);
    }
    ExitCode::SUCCESS
}
