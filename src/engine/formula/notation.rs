//! A formula as a physicist writes it, parsed into an expression tree by
//! the mathematical conventions: `-a^b = -(a^b)`, `a^b^c = a^(b^c)`,
//! `a^-b = a^(-b)`, `+ -` below `* /` below a sign below `^` (precedence
//! climbing). Implicit multiplication (`2a`, `2(a+b)`, `a b`) is refused
//! rather than guessed.
//!
//! Why not exmex's own parser: it gives unary minus priority over `^`, so
//! `-w^2*x` meant `(-w)^2*x = +w^2*x`, and it reads `a^b^c` from the left.
//! The tree also prints itself fully parenthesized ([`Expr::explicit`]),
//! which the tests hand to exmex as an independent evaluator.

use anyhow::{bail, Result};

/// A parsed formula.
#[derive(Clone, Debug, PartialEq)]
pub enum Expr {
    Number(f64),
    Name(String),
    Neg(Box<Expr>),
    /// `+ - * / ^` and its two operands.
    Binary(char, Box<Expr>, Box<Expr>),
    /// A function and its arguments: `max(a, b)`.
    Call(String, Vec<Expr>),
}

impl Expr {
    /// The formula with every operation in parentheses: `-w^2` → `(-(w^2))`.
    #[cfg(test)]
    pub fn explicit(&self) -> String {
        match self {
            Expr::Number(v) => format!("{v:?}"),
            Expr::Name(n) => n.clone(),
            Expr::Neg(a) => format!("(-{})", a.explicit()),
            Expr::Binary(op, a, b) => format!("({}{op}{})", a.explicit(), b.explicit()),
            Expr::Call(f, args) => format!("{f}({})", args.iter().map(Expr::explicit).collect::<Vec<_>>().join(", ")),
        }
    }

    /// Every name the formula uses outside function position, each once.
    pub fn names(&self, out: &mut Vec<String>) {
        match self {
            Expr::Number(_) => {}
            Expr::Name(n) => {
                if !out.contains(n) {
                    out.push(n.clone())
                }
            }
            Expr::Neg(a) => a.names(out),
            Expr::Binary(_, a, b) => {
                a.names(out);
                b.names(out);
            }
            Expr::Call(_, args) => args.iter().for_each(|a| a.names(out)),
        }
    }

    /// The formula's degree as a polynomial in the names `of` picks out (0:
    /// free of them); None when it is not a polynomial in them (a quotient
    /// or function of one, or a power other than a whole number).
    /// Coefficients may be any formula of the other names: `-w^2*x` has
    /// degree 1 in x.
    pub fn degree(&self, of: &dyn Fn(&str) -> bool) -> Option<u32> {
        match self {
            Expr::Number(_) => Some(0),
            Expr::Name(n) => Some(u32::from(of(n))),
            Expr::Neg(a) => a.degree(of),
            Expr::Binary(op, a, b) => {
                let (da, db) = (a.degree(of)?, b.degree(of)?);
                match (op, b.as_ref()) {
                    ('+' | '-', _) => Some(da.max(db)),
                    ('*', _) => Some(da + db),
                    ('/', _) if db == 0 => Some(da),
                    ('^', _) if da == 0 && db == 0 => Some(0),
                    // x^2: a whole power of a polynomial.
                    ('^', Expr::Number(k)) if k.fract() == 0.0 && (0.0..=64.0).contains(k) => Some(da * *k as u32),
                    _ => None,
                }
            }
            Expr::Call(_, args) => {
                let free = args.iter().all(|a| a.degree(of) == Some(0));
                free.then_some(0)
            }
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
enum Token {
    Number(String),
    Name(String),
    Op(char),
    Open,
    Close,
    Comma,
}

/// The expression tree of `text`; an error says what is wrong.
pub fn parse(text: &str) -> Result<Expr> {
    let tokens = tokenize(text)?;
    let mut parser = Parser { tokens: &tokens, at: 0, depth: 0 };
    let out = parser.sum()?;
    if let Some(t) = parser.peek() {
        bail!("unexpected {} after a complete expression", describe(t));
    }
    Ok(out)
}

fn tokenize(text: &str) -> Result<Vec<Token>> {
    let chars: Vec<char> = text.chars().collect();
    let mut tokens = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if c.is_whitespace() {
            i += 1;
            continue;
        }
        let token = if c.is_ascii_digit() || (c == '.' && chars.get(i + 1).is_some_and(|d| d.is_ascii_digit())) {
            let (number, next) = read_number(&chars, i);
            i = next;
            Token::Number(number)
        } else if c.is_alphabetic() || c == '_' {
            let start = i;
            while i < chars.len() && (chars[i].is_alphanumeric() || chars[i] == '_') {
                i += 1;
            }
            Token::Name(chars[start..i].iter().collect())
        } else {
            i += 1;
            match c {
                '+' | '-' | '*' | '/' | '^' => Token::Op(c),
                '(' => Token::Open,
                ')' => Token::Close,
                ',' => Token::Comma,
                _ => bail!("unexpected character '{c}'"),
            }
        };
        if let (Some(prev), true) = (tokens.last(), starts_operand(&token)) {
            // A name before '(' is a function call: `sin(t)`.
            let call = matches!((prev, &token), (Token::Name(_), Token::Open));
            if ends_operand(prev) && !call {
                bail!("{} directly after {}: write the multiplication out, e.g. 2*a", describe(&token), describe(prev));
            }
        }
        tokens.push(token);
        if tokens.len() > MAX_TOKENS {
            bail!("the formula has more than {MAX_TOKENS} numbers, names and operators");
        }
    }
    Ok(tokens)
}

/// Digits, an optional fraction and an optional exponent (`1.5e-3`).
fn read_number(chars: &[char], mut i: usize) -> (String, usize) {
    let start = i;
    while i < chars.len() && (chars[i].is_ascii_digit() || chars[i] == '.') {
        i += 1;
    }
    if i < chars.len() && (chars[i] == 'e' || chars[i] == 'E') {
        let mut j = i + 1;
        if j < chars.len() && (chars[j] == '+' || chars[j] == '-') {
            j += 1;
        }
        if j < chars.len() && chars[j].is_ascii_digit() {
            while j < chars.len() && chars[j].is_ascii_digit() {
                j += 1;
            }
            i = j;
        }
    }
    (chars[start..i].iter().collect(), i)
}

/// `text` with every use of the name `name` (not a function of that name,
/// nor a longer name containing it) replaced by `(by)`: a parameter made a
/// function of the input wherever the model uses it.
pub fn rename(text: &str, name: &str, by: &str) -> String {
    let chars: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if c.is_ascii_digit() || (c == '.' && chars.get(i + 1).is_some_and(|d| d.is_ascii_digit())) {
            let (number, next) = read_number(&chars, i);
            out.push_str(&number);
            i = next;
        } else if c.is_alphabetic() || c == '_' {
            let start = i;
            while i < chars.len() && (chars[i].is_alphanumeric() || chars[i] == '_') {
                i += 1;
            }
            let word: String = chars[start..i].iter().collect();
            let called = chars[i..].iter().find(|c| !c.is_whitespace()) == Some(&'(');
            if word == name && !called {
                out.push_str(&format!("({by})"));
            } else {
                out.push_str(&word);
            }
        } else {
            out.push(c);
            i += 1;
        }
    }
    out
}

impl Expr {
    /// How many operations the formula has (operators, signs and function
    /// calls but `abs`, a whole power `x^k` as its k − 1 products, so `c*x^3`
    /// is the size of `c*x*x*x`): the size a prior over forms charges for.
    pub fn operations(&self) -> usize {
        match self {
            Expr::Number(_) | Expr::Name(_) => 0,
            Expr::Neg(a) => 1 + a.operations(),
            Expr::Binary('^', a, b) => match b.as_ref() {
                Expr::Number(k) if k.fract() == 0.0 && (2.0..=64.0).contains(k) => *k as usize - 1 + a.operations(),
                _ => 1 + a.operations() + b.operations(),
            },
            Expr::Binary(_, a, b) => 1 + a.operations() + b.operations(),
            // abs is free: `v*abs(v)` is how physics writes an even power of
            // a signed quantity (drag against the motion), no rarer than `v*v`.
            Expr::Call(f, args) => usize::from(f != "abs") + args.iter().map(Expr::operations).sum::<usize>(),
        }
    }
}

fn starts_operand(t: &Token) -> bool {
    matches!(t, Token::Number(_) | Token::Name(_) | Token::Open)
}

fn ends_operand(t: &Token) -> bool {
    matches!(t, Token::Number(_) | Token::Name(_) | Token::Close)
}

fn describe(t: &Token) -> String {
    match t {
        Token::Number(n) => format!("number {n}"),
        Token::Name(n) => format!("name '{n}'"),
        Token::Op(c) => format!("'{c}'"),
        Token::Open => "'('".into(),
        Token::Close => "')'".into(),
        Token::Comma => "','".into(),
    }
}

struct Parser<'a> {
    tokens: &'a [Token],
    at: usize,
    /// Open parentheses, calls and signs being parsed: the recursion depth.
    depth: usize,
}

/// The deepest nesting a formula may have; deeper ones are refused rather
/// than left to overflow the stack.
const MAX_NESTING: usize = 200;

/// The most numbers, names and operators a formula may hold: a chain
/// `a + b + …` is a tree as deep as it is long, which compilation walks
/// recursively.
const MAX_TOKENS: usize = 2000;

impl Parser<'_> {
    fn peek(&self) -> Option<&Token> {
        self.tokens.get(self.at)
    }

    fn next(&mut self) -> Option<&Token> {
        self.at += 1;
        self.tokens.get(self.at - 1)
    }

    fn eat_op(&mut self, ops: &[char]) -> Option<char> {
        match self.peek() {
            Some(Token::Op(c)) if ops.contains(c) => {
                let c = *c;
                self.at += 1;
                Some(c)
            }
            _ => None,
        }
    }

    /// One level deeper (a parenthesis, a call's arguments, a sign).
    fn descend(&mut self) -> Result<()> {
        self.depth += 1;
        if self.depth > MAX_NESTING {
            bail!("the formula nests more than {MAX_NESTING} levels deep");
        }
        Ok(())
    }

    /// `a + b - c`, left to right.
    fn sum(&mut self) -> Result<Expr> {
        self.descend()?;
        let out = self.sum_here();
        self.depth -= 1;
        out
    }

    fn sum_here(&mut self) -> Result<Expr> {
        let mut out = self.product()?;
        while let Some(op) = self.eat_op(&['+', '-']) {
            out = Expr::Binary(op, Box::new(out), Box::new(self.product()?));
        }
        Ok(out)
    }

    /// `a * b / c`, left to right.
    fn product(&mut self) -> Result<Expr> {
        let mut out = self.signed()?;
        while let Some(op) = self.eat_op(&['*', '/']) {
            out = Expr::Binary(op, Box::new(out), Box::new(self.signed()?));
        }
        Ok(out)
    }

    /// A leading sign applies to the whole power after it: `-a^b = -(a^b)`.
    fn signed(&mut self) -> Result<Expr> {
        self.descend()?;
        let out = match self.eat_op(&['-', '+']) {
            Some('-') => self.signed().map(|e| Expr::Neg(Box::new(e))),
            Some(_) => self.signed(),
            None => self.power(),
        };
        self.depth -= 1;
        out
    }

    /// `a ^ b`, right to left, the exponent may carry a sign: `a^-b^c = a^(-(b^c))`.
    fn power(&mut self) -> Result<Expr> {
        let base = self.atom()?;
        if self.eat_op(&['^']).is_some() {
            return Ok(Expr::Binary('^', Box::new(base), Box::new(self.signed()?)));
        }
        Ok(base)
    }

    fn atom(&mut self) -> Result<Expr> {
        match self.next().cloned() {
            Some(Token::Number(n)) => match n.parse::<f64>() {
                Ok(v) => Ok(Expr::Number(v)),
                Err(_) => bail!("'{n}' is not a number"),
            },
            Some(Token::Name(name)) if self.peek() == Some(&Token::Open) => {
                self.at += 1;
                let mut args = vec![self.sum()?];
                while self.peek() == Some(&Token::Comma) {
                    self.at += 1;
                    args.push(self.sum()?);
                }
                self.expect_close(&format!("the arguments of {name}"))?;
                Ok(Expr::Call(name, args))
            }
            Some(Token::Name(name)) => Ok(Expr::Name(name)),
            Some(Token::Open) => {
                let inner = self.sum()?;
                self.expect_close("a parenthesis")?;
                Ok(inner)
            }
            Some(t) => bail!("expected a number, a name or '(' but found {}", describe(&t)),
            None => bail!("the formula ends where a number, a name or '(' was expected"),
        }
    }

    fn expect_close(&mut self, what: &str) -> Result<()> {
        match self.next() {
            Some(Token::Close) => Ok(()),
            Some(t) => bail!("{what} is not closed: found {} where ')' was expected", describe(t)),
            None => bail!("{what} is not closed: ')' is missing"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn groups_by_mathematical_precedence() {
        for (text, want) in [
            ("-w^2*x", "((-(w^2.0))*x)"),
            ("a^b^c", "(a^(b^c))"),
            ("a^-b", "(a^(-b))"),
            ("-a^-b^c", "(-(a^(-(b^c))))"),
            ("a - b - c", "((a-b)-c)"),
            ("a / b / c", "((a/b)/c)"),
            ("a/b*c", "((a/b)*c)"),
            ("2.5e-3*x^2", "(0.0025*(x^2.0))"),
            ("max(a, -b^2)", "max(a, (-(b^2.0)))"),
            ("--a", "(-(-a))"),
            ("+a", "a"),
            ("(a+b)^2", "((a+b)^2.0)"),
        ] {
            assert_eq!(parse(text).unwrap().explicit(), want, "{text}");
        }
    }

    #[test]
    fn degree_counts_only_the_chosen_names() {
        let states = |n: &str| n == "x" || n == "v";
        for (text, want) in [
            ("-w^2*x", Some(1)),
            ("v", Some(1)),
            ("g - k*v/m", Some(1)),
            ("u*c", Some(0)),
            ("exp(-l)*x + sin(w)", Some(1)),
            ("x*v", Some(2)),
            ("-b*x^3", Some(3)),
            ("k*v*abs(v)", None),
            ("u*y/(1 + m*x)", None),
            ("x^a", None),
            ("2^x", None),
        ] {
            assert_eq!(parse(text).unwrap().degree(&states), want, "{text}");
        }
    }

    #[test]
    fn refuses_implicit_products_and_broken_syntax() {
        for (text, says) in [
            ("2a", "write the multiplication out"),
            ("2(a+b)", "write the multiplication out"),
            ("(a)(b)", "write the multiplication out"),
            ("a b", "write the multiplication out"),
            ("a +", "ends where"),
            ("(a", "not closed"),
            ("a)", "unexpected ')'"),
            ("a # b", "unexpected character '#'"),
            ("*a", "found '*'"),
        ] {
            let e = parse(text).unwrap_err().to_string();
            assert!(e.contains(says), "{text}: {e}");
        }
        // Nesting that would overflow the stack is refused, not followed.
        for text in ["(".repeat(600) + "a" + &")".repeat(600), "-".repeat(600) + "a", "a^".repeat(600) + "a"] {
            assert!(parse(&text).unwrap_err().to_string().contains("levels deep"), "{}", &text[..20]);
        }
        assert!(parse(&"a+".repeat(100_000)).unwrap_err().to_string().contains("more than 2000"));
    }

    #[test]
    fn rename_replaces_the_name_only() {
        assert_eq!(
            rename("-k*y + k2*exp(k) + 1e-3*k", "k", "k*(1 + c*T)"),
            "-(k*(1 + c*T))*y + k2*exp((k*(1 + c*T))) + 1e-3*(k*(1 + c*T))"
        );
        // A function of the same name and a number's exponent are not the name.
        assert_eq!(rename("e(x) + 2e5 + e", "e", "q"), "e(x) + 2e5 + (q)");
        assert_eq!(parse("a*sin(w*t) + b*cos(w*t)").unwrap().operations(), 7);
        assert_eq!(parse("-c*x^2").unwrap().operations(), 3);
        assert_eq!(parse("c*x^4").unwrap().operations(), parse("c*x*x*x*x").unwrap().operations());
        assert_eq!(parse("c*v*abs(v)").unwrap().operations(), parse("c*v^2").unwrap().operations());
    }
}
