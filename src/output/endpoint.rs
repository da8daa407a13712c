//! MAVLink UDP endpoints written as mavlink-router / MAVProxy users write them.
//!
//! * `udpout:HOST:PORT` — we send to HOST:PORT from an ephemeral port (and read the replies that
//!   come back to it). Use it towards mavlink-router's or MAVProxy's UDP server, or a GCS.
//! * `udpin:HOST:PORT` — we listen on HOST:PORT and send to whoever sent us the last datagram;
//!   nothing is sent before the first datagram arrives (the FC's heartbeat usually).
//!
//! HOST is an IPv4 address, a bracketed IPv6 address (`[::1]`) or a host name.

use std::fmt;
use std::net::{SocketAddr, ToSocketAddrs, UdpSocket};
use std::str::FromStr;

/// A parsed endpoint (not yet resolved or opened).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Endpoint {
    UdpOut { host: String, port: u16 },
    UdpIn { host: String, port: u16 },
}

/// Why an endpoint could not be parsed or opened; the message names the endpoint text.
#[derive(Debug, thiserror::Error)]
pub enum EndpointError {
    #[error(
        "endpoint '{text}': {msg} (expected udpout:HOST:PORT or udpin:HOST:PORT, \
         e.g. udpout:127.0.0.1:14550)"
    )]
    Syntax { text: String, msg: String },
    #[error("endpoint '{endpoint}': cannot resolve host: {source}")]
    Resolve {
        endpoint: String,
        #[source]
        source: std::io::Error,
    },
    #[error("endpoint '{endpoint}': cannot open UDP socket on {addr}: {source}")]
    Bind {
        endpoint: String,
        addr: SocketAddr,
        #[source]
        source: std::io::Error,
    },
}

impl FromStr for Endpoint {
    type Err = EndpointError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let err = |msg: &str| EndpointError::Syntax {
            text: text.to_string(),
            msg: msg.to_string(),
        };
        let (scheme, rest) = text
            .split_once(':')
            .ok_or_else(|| err("no ':' after the scheme"))?;
        let (host, port) = rest
            .rsplit_once(':')
            .ok_or_else(|| err("missing ':PORT'"))?;
        if host.is_empty() {
            return Err(err("empty HOST"));
        }
        let port: u16 = port
            .parse()
            .map_err(|_| err(&format!("port '{port}' is not 1-65535")))?;
        if port == 0 {
            return Err(err("port 0 is not a destination"));
        }
        let host = host.to_string();
        match scheme {
            "udpout" => Ok(Endpoint::UdpOut { host, port }),
            "udpin" => Ok(Endpoint::UdpIn { host, port }),
            other => Err(err(&format!("unknown scheme '{other}'"))),
        }
    }
}

impl fmt::Display for Endpoint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Endpoint::UdpOut { host, port } => write!(f, "udpout:{host}:{port}"),
            Endpoint::UdpIn { host, port } => write!(f, "udpin:{host}:{port}"),
        }
    }
}

/// An opened endpoint: the socket, and the fixed destination for `udpout`.
#[derive(Debug)]
pub struct OpenEndpoint {
    pub socket: UdpSocket,
    /// `Some` for udpout; `None` for udpin (the destination is learned from received datagrams).
    pub fixed_peer: Option<SocketAddr>,
}

impl Endpoint {
    fn resolve(&self) -> Result<SocketAddr, EndpointError> {
        let (host, port) = match self {
            Endpoint::UdpOut { host, port } | Endpoint::UdpIn { host, port } => (host, *port),
        };
        let bare = host.trim_start_matches('[').trim_end_matches(']');
        let resolve_err = |source| EndpointError::Resolve {
            endpoint: self.to_string(),
            source,
        };
        (bare, port)
            .to_socket_addrs()
            .map_err(resolve_err)?
            .next()
            .ok_or_else(|| {
                resolve_err(std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    "no address",
                ))
            })
    }

    /// Resolves the host and opens the socket.
    pub fn open(&self) -> Result<OpenEndpoint, EndpointError> {
        let addr = self.resolve()?;
        let bind = |a: SocketAddr| {
            UdpSocket::bind(a).map_err(|source| EndpointError::Bind {
                endpoint: self.to_string(),
                addr: a,
                source,
            })
        };
        match self {
            Endpoint::UdpOut { .. } => {
                let any: SocketAddr = if addr.is_ipv4() {
                    ([0, 0, 0, 0], 0).into()
                } else {
                    (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
                };
                Ok(OpenEndpoint {
                    socket: bind(any)?,
                    fixed_peer: Some(addr),
                })
            }
            Endpoint::UdpIn { .. } => Ok(OpenEndpoint {
                socket: bind(addr)?,
                fixed_peer: None,
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_router_style_endpoints() {
        assert_eq!(
            "udpout:127.0.0.1:14550".parse::<Endpoint>().unwrap(),
            Endpoint::UdpOut {
                host: "127.0.0.1".into(),
                port: 14550
            }
        );
        let e: Endpoint = "udpin:0.0.0.0:14540".parse().unwrap();
        assert_eq!(
            e,
            Endpoint::UdpIn {
                host: "0.0.0.0".into(),
                port: 14540
            }
        );
        assert_eq!(e.to_string(), "udpin:0.0.0.0:14540");
        let v6: Endpoint = "udpout:[::1]:14550".parse().unwrap();
        assert_eq!(
            v6,
            Endpoint::UdpOut {
                host: "[::1]".into(),
                port: 14550
            }
        );
    }

    #[test]
    fn errors_name_the_text_and_the_problem() {
        for (text, needle) in [
            ("tcp:1.2.3.4:5760", "unknown scheme 'tcp'"),
            ("udpout:127.0.0.1", "missing ':PORT'"),
            ("udpout:127.0.0.1:x", "port 'x'"),
            ("udpout:127.0.0.1:99999", "port '99999'"),
            ("udpout::14550", "empty HOST"),
            ("/dev/ttyACM0", "no ':'"),
        ] {
            let msg = text.parse::<Endpoint>().unwrap_err().to_string();
            assert!(msg.contains(text) && msg.contains(needle), "{text}: {msg}");
        }
    }

    #[test]
    fn opens_udpout_and_udpin_on_loopback() {
        let o: Endpoint = "udpout:127.0.0.1:14550".parse().unwrap();
        let open = o.open().unwrap();
        assert_eq!(open.fixed_peer, Some("127.0.0.1:14550".parse().unwrap()));
        // udpin on a port that is taken fails with an error naming the endpoint and the cause.
        let taken = UdpSocket::bind("127.0.0.1:0").unwrap();
        let port = taken.local_addr().unwrap().port();
        let i = Endpoint::UdpIn {
            host: "127.0.0.1".into(),
            port,
        };
        let msg = i.open().unwrap_err().to_string();
        assert!(
            msg.contains(&format!("udpin:127.0.0.1:{port}")) && msg.contains("cannot open"),
            "{msg}"
        );
        drop(taken);
    }
}
